"""Typed settings: one schema type, :class:`Param`, for run settings, budgets and method parameters.

A :class:`Param` states one setting's type, default, bounds, choices and help text. Dataclasses
(the run configuration, the fitting and training budgets) declare their fields with
:func:`setting`, so the field, its check and its ``--help`` text are one declaration, and
:func:`check_fields` types every field when the dataclass is built. A method declares its extractor
parameters as a ``{name: Param}`` table. Every value a user gives (command line, config file,
sweep, ``--method-param``, ``--budget-param``) is parsed by the same :meth:`Param.parse`, so text
from the command line equals the same value from a TOML file, and a typo is refused before any work
starts instead of being read as the wrong thing:

* bool: ``true/false/yes/no/on/off/1/0`` (any case) or a real bool; anything else is refused
  (``bool('False')`` is True in Python: never used);
* int: an integer (``'4'``, ``4.0``; not ``'4.5'``); float: any finite number (``'0.2'``, ``'1e-3'``);
* str: one of ``choices`` when given;
* tuple: a list or tuple of ``item`` values (a lone value is a tuple of one), each parsed and
  bounded as above;
* dict: a mapping with str keys whose values are scalars (``item=None``), lists of scalars
  (``item=tuple``) or mappings of scalars (``item=dict``); the values are typed later by the
  settings they name (a method's parameters, a budget's fields, a sweep key);
* ranges: ``gt``/``ge``/``lt``/``le`` bounds, e.g. a threshold in (0, 1) is ``Param(0.1, gt=0, lt=1)``;
* None: allowed where ``optional`` is set or the default is None.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

_TRUE = {"true", "yes", "on", "1"}
_FALSE = {"false", "no", "off", "0"}
_SCALARS = (bool, int, float, str)


class ParamError(ValueError):
    """A parameter value that does not parse or lies outside its range (one line)."""


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


#: The default of a setting that has none (a dataclass field without a default).
REQUIRED = _Required()


@dataclass(frozen=True)
class Param:
    """One setting: default, help text, optional bounds and choices.

    kind : the value's type (bool, int, float, str, tuple or dict); the default's type when not given.
    item : the type of a tuple's items (bool, int, float, str), or a dict's values (module docstring).
    optional : None is a valid value (also when the default is None).
    neural_only : a method parameter read only by the neural field's query (the exact field ignores it).
    fit : a method parameter read by the fit (its inputs, targets or loss): part of the fitted weights' key.
    """

    default: Any = REQUIRED
    help: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    kind: type | None = None
    item: type | None = None
    optional: bool = False
    neural_only: bool = False
    fit: bool = False

    def __post_init__(self):
        if self.kind is None:
            if self.default is None or self.default is REQUIRED:
                raise TypeError("Param: a setting without a default value needs kind=")
            object.__setattr__(self, "kind", type(self.default))
        if self.kind is tuple and self.item not in _SCALARS:
            raise TypeError("Param: a tuple setting needs item= one of bool, int, float, str")

    @property
    def nullable(self) -> bool:
        return self.optional or self.default is None

    def scalar(self) -> "Param":
        """This setting's single value: a tuple's item type, never None (a sweep's values)."""
        if self.kind is tuple:
            return dataclasses.replace(self, default=REQUIRED, kind=self.item, item=None, optional=False)
        return dataclasses.replace(self, default=REQUIRED if self.default is None else self.default, optional=False)

    def describe(self) -> str:
        """Type and allowed values, e.g. 'float in (0, 1)' or "str, one of 'fan4', 'quad2'"."""
        text = (f"tuple of {self.item.__name__}" if self.kind is tuple else
                "table" if self.kind is dict else self.kind.__name__)
        if self.choices:
            return f"{text}, one of " + ", ".join(repr(c) for c in self.choices)
        lo = f"({_number(self.gt)}" if self.gt is not None else (f"[{_number(self.ge)}" if self.ge is not None else None)
        hi = f"{_number(self.lt)})" if self.lt is not None else (f"{_number(self.le)}]" if self.le is not None else None)
        if lo or hi:
            text += f" in {lo or '(-inf'}, {hi or 'inf)'}"
        return text

    def parse(self, value: Any, name: str) -> Any:
        """``value`` as this setting's type, checked; :class:`ParamError` names ``name`` otherwise."""
        if value is None and self.nullable:
            return None
        try:
            if self.kind is tuple:
                items = [value] if isinstance(value, _SCALARS) else list(value)
                return tuple(self._item(v, name) for v in items)
            if self.kind is dict:
                return self._mapping(value)
            return self._checked(self._scalar(value, self.kind), value, name)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ParamError):
                raise
            raise ParamError(f"{name}={value!r}: expected {self.describe()}") from None

    def _item(self, value: Any, name: str) -> Any:
        try:
            return self._checked(self._scalar(value, self.item), value, name)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ParamError):
                raise
            raise ParamError(f"{name}={value!r}: expected {self.describe()}") from None

    def _checked(self, out: Any, value: Any, name: str) -> Any:
        bounds = ((self.gt, lambda v, b: v > b), (self.ge, lambda v, b: v >= b),
                  (self.lt, lambda v, b: v < b), (self.le, lambda v, b: v <= b))
        if (self.choices is not None and out not in self.choices) or any(
                b is not None and not ok(out, b) for b, ok in bounds):
            raise ParamError(f"{name}={value!r}: expected {self.describe()}")
        return out

    @staticmethod
    def _scalar(value: Any, kind: type) -> Any:
        if kind is bool:
            return _bool(value)
        if kind is int:
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise ValueError
            if not isinstance(value, (int, float, str)):
                raise TypeError
            return int(value.strip()) if isinstance(value, str) else int(value)
        if kind is float:
            if isinstance(value, bool) or not isinstance(value, (int, float, str)):
                raise TypeError
            out = float(value)
            if not math.isfinite(out):
                raise ValueError
            return out
        if kind is str:
            if not isinstance(value, str):
                raise TypeError
            return value
        raise TypeError

    def _mapping(self, value: Any) -> dict:
        if not isinstance(value, Mapping):
            raise TypeError
        out = {}
        for key, v in value.items():
            if self.item is dict:
                if not isinstance(v, Mapping) or not all(isinstance(x, _SCALARS) for x in v.values()):
                    raise TypeError
                v = {str(k): x for k, x in v.items()}
            elif self.item is tuple:
                if not isinstance(v, (list, tuple)) or not all(isinstance(x, _SCALARS) for x in v):
                    raise TypeError
                v = tuple(v)
            elif not isinstance(v, _SCALARS):
                raise TypeError
            out[str(key)] = v
        return out


def _number(bound: float) -> str:
    """A bound as text: ints exactly (2^k - 1 as such), floats in %g."""
    if isinstance(bound, int):
        return f"2^{bound.bit_length()}-1" if bound >= 2**31 and (bound + 1) & bound == 0 else str(bound)
    return f"{bound:g}"


def _bool(value: Any) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str):
        text = value.strip().lower()
        if text in _TRUE:
            return True
        if text in _FALSE:
            return False
    raise ValueError


# -- dataclasses declared with Params ----------------------------------------------------------------

def setting(param: Param, **metadata: Any) -> Any:
    """A dataclass field declared by ``param`` (its default, or none when ``REQUIRED``); ``metadata``
    adds facts the owner reads (a run setting's ``role``, a budget value's ``override``)."""
    meta = {"param": param, **metadata}
    if param.default is REQUIRED:
        return dataclasses.field(metadata=meta)
    if isinstance(param.default, dict):
        return dataclasses.field(default_factory=dict, metadata=meta)
    return dataclasses.field(default=param.default, metadata=meta)


def params_of(cls, **metadata: Any) -> dict[str, Param]:
    """``{field name: Param}`` of a dataclass declared with :func:`setting`, in field order; only the
    fields whose metadata has every given ``key=value``."""
    return {f.name: f.metadata["param"] for f in dataclasses.fields(cls) if "param" in f.metadata
            and all(f.metadata.get(k) == v for k, v in metadata.items())}


def check_fields(instance, what: str) -> None:
    """Parse every :func:`setting` field of a frozen dataclass ``instance`` in place (named
    ``what: FIELD`` in messages, or ``FIELD`` when ``what`` is empty); :class:`ParamError` otherwise."""
    for name, param in params_of(type(instance)).items():
        label = f"{what}: {name}" if what else name
        object.__setattr__(instance, name, param.parse(getattr(instance, name), label))


def parsed_values(params: Mapping[str, Param], given: Mapping[str, Any], what: str) -> dict[str, Any]:
    """Every parameter of ``params`` at its default, with ``given`` parsed and checked over it (named
    ``what.NAME`` in messages); :class:`ParamError` naming unknown names and the known ones."""
    unknown = sorted(set(given) - set(params))
    if unknown:
        raise ParamError(f"{what} has no parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(params)) or 'none'}")
    values = {k: p.default for k, p in params.items()}
    values.update({k: params[k].parse(v, f"{what}.{k}") for k, v in given.items()})
    return values


def with_overrides(base, overrides: Mapping[str, Any] | None, params: Mapping[str, Param], what: str):
    """The frozen dataclass ``base`` with ``overrides`` applied, each typed and checked by its
    :class:`Param` in ``params`` (named ``what.NAME`` in messages); unknown names list the known ones."""
    if not overrides:
        return base
    unknown = sorted(set(overrides) - set(params))
    if unknown:
        raise ParamError(f"{what} has no setting '{unknown[0]}' that a run may change; known: {', '.join(sorted(params))}")
    return dataclasses.replace(base, **{k: params[k].parse(v, f"{what}.{k}") for k, v in overrides.items()})
