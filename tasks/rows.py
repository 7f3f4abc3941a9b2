"""The rows of a run's tables, per task, and what the run layer knows of each (:class:`RowKind`).

A row of the ``encode`` and ``reconstruct`` tasks is a registered method (:mod:`methods.base`); a
row of the ``score`` task is a folder of meshes made elsewhere, under the name the user gives it
(:func:`tasks.score.predictions_row`), known only to the run that scores it: nothing is registered.
The run layer plans, keys and digests every row from its :class:`RowKind` (:func:`row_kind`), so it
never asks which task or method a row belongs to.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from foundation.params import Param, parsed_values

__all__ = ["RowKind", "ROW_SOURCES", "method_row", "predictions_row", "row_kind"]


@dataclass(frozen=True)
class RowKind:
    """What the run layer needs to know of one row of a task's tables.

    name, task : the row's name in the tables and the task it belongs to.
    parameters : its settings (``--method-param NAME.PARAM=VALUE``), typed and checked by :class:`Param`.
    module : the module that computes it (its code digest: :func:`tasks.cache.task_code_modules`).
    learned : a network trained across shapes (the run records its training set).
    budget_family : the budget family its fit or training reads; None: no budget applies.
    budget_fields : the budget settings it reads.
    components : the parts of its grid field ``--decompose`` may take from the exact field.
    fit_name : the name its fitted weights are keyed under (a row extracting another's fit).
    unavailable : why it cannot run on this machine, or None.
    note : the sentence every table caption of a run with the row carries ('' for none).
    check : further checks of its parameters once parsed (raises ValueError, one line), or None.
    """

    name: str
    task: str
    parameters: Mapping[str, Param]
    module: str
    learned: bool = False
    budget_family: str | None = None
    budget_fields: frozenset[str] = frozenset()
    components: tuple[str, ...] = ()
    fit_name: str = ""
    unavailable: str | None = None
    note: str = ""
    check: Callable[[dict[str, Any]], None] | None = field(default=None, compare=False)

    def checked_params(self, given: Mapping[str, Any]) -> dict[str, Any]:
        """Every parameter at its default with ``given`` parsed over it, then :attr:`check`ed
        (:class:`foundation.params.ParamError` or ValueError, one line)."""
        values = parsed_values(self.parameters, given, self.name)
        if self.check is not None:
            try:
                self.check(values)
            except ValueError as exc:
                raise ValueError(f"{self.name}.{exc}") from None
        return values


def method_row(name: str) -> RowKind:
    """The row of the registered method ``name`` (ValueError listing the known ones)."""
    from methods.base import METHODS, presentation

    cls = METHODS.get(name)
    return RowKind(name=name, task=cls.task, parameters=cls.parameters, module=cls.__module__, learned=cls.learned,
                   budget_family=cls.budget_family, budget_fields=cls.budget_fields(),
                   components=tuple(cls.components), fit_name=cls.fit_name, unavailable=cls.unavailable(),
                   note=presentation(name).note)


def predictions_row(name: str, params: Mapping[str, Any] | None = None) -> RowKind:
    """The score task's row ``name``: meshes made outside this run, read from the folder its
    parameters name (:mod:`tasks.score`); ``params``, when given, name the folder and frame in its
    note. A built-in method's name is refused (its rows would be mistaken for the method's)."""
    from methods.base import METHODS
    from tasks.score import PARAMETERS, check_predictions

    if name in METHODS:
        raise ValueError(f"'{name}' is a built-in method: give the predictions another --name")
    where = f" from {params['pred_dir']} ({params.get('pred_frame', 'original')} frame)" if params else ""
    return RowKind(name=name, task="score", parameters=PARAMETERS, module="tasks.score",
                   note=f"{name}: meshes made outside this run{where}, scored as given.", check=check_predictions)


#: How each task's rows are found by name: the score task's are its predictions, the others' methods.
ROW_SOURCES: dict[str, Callable[..., RowKind]] = {"score": predictions_row}


def row_kind(task: str, name: str, params: Mapping[str, Any] | None = None) -> RowKind:
    """The row ``name`` of ``task`` (:data:`ROW_SOURCES`, else the registered method of that name);
    ``params`` only enter a note that names them. ValueError (one line) for an unknown name."""
    source = ROW_SOURCES.get(task)
    return source(name, params) if source is not None else method_row(name)
