"""Meshes made elsewhere, scored as a method row: the ``score`` task (``run_benchmark.py score``).

A folder of predicted meshes becomes the method ``NAME`` of a run of ``--task score``: each of the
dataset's shapes is a job of :mod:`tasks.score` that reads its prediction, moves it into the
canonical frame and scores it with the run's metric protocol, beside the same floor rows and tables
as any run, so ``run_benchmark.py report runs/A runs/B`` puts it beside the built-in methods on the
same shapes. Which file is a shape's prediction, the frames and the seconds file: :mod:`tasks.score`.
"""

from __future__ import annotations

from foundation.params import Param
from methods.base import METHODS, Method, register_method
from tasks.score import FRAMES

__all__ = ["ExternalMeshes", "register_external"]


class ExternalMeshes(Method):
    """A method whose meshes were made outside this run; :func:`register_external` makes one per name."""

    description = "meshes made outside this run, read from a folder and scored"
    extractor = "external"
    task = "score"
    budget_family = None
    parameters = {
        "pred_dir": Param("", "folder of the predicted meshes (<shape>.<ext> or <shape>/<name>.<ext>)"),
        "pred_frame": Param("original", "the frame of the predictions: original (the GT file's) or canonical",
                            choices=FRAMES),
    }


def register_external(name: str, pred_dir: str = "", pred_frame: str = "original") -> type[Method]:
    """Register (once per process) the :class:`ExternalMeshes` method ``name``; its caption note
    names the folder and the frame. A registered non-external method of that name is refused."""
    if name in METHODS:
        existing = METHODS.get(name)
        if not issubclass(existing, ExternalMeshes):
            raise ValueError(f"'{name}' is a built-in method: give the predictions another --name")
        return existing
    cls = type(f"External_{name}", (ExternalMeshes,), {"name": name, "__module__": __name__})
    where = f" from {pred_dir}" if pred_dir else ""
    return register_method(cls, order=10_000, note=f"{name}: meshes made outside this run{where} ({pred_frame} "
                                                   "frame), scored as given.")
