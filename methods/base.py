"""The representation interface and its registry.

A *method* is a representation + surface extraction: what the network predicts (its field), the
exact field it learns from (computed from the mesh), its loss and its extractor. Each method lives in
one file under ``methods/`` and declares itself with :func:`register_method`; the runner only ever
calls :func:`get_method` and the interface below, so adding a method is adding one file.

Data flow (one way): ``Shape`` -> shared ``Samples`` (benchmark.sampler) -> ``Method.training_targets``
(from ``benchmark.fields.ExactFields``) -> shared fitting loop (methods.fitting) -> ``Method.neural_grid``
or ``Method.oracle_grid`` (the field on the grid the extractor needs) -> ``Method.extract`` ->
``Extraction`` (mesh in the canonical frame + stage timings).
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np


@dataclass
class Extraction:
    """A mesh extracted by a method, canonical frame, plus per-stage wall-clock seconds.

    ``timings`` keys end in ``_s``; ``query_s`` is the time spent evaluating the field (network or
    exact) on the grid; extraction steps are named ``extract_<step>_s`` (e.g. ``extract_qef_s``).
    """

    vertices: np.ndarray
    faces: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


class Method:
    """Base class of a representation. Subclasses set the class attributes and implement the hooks.

    Class attributes
    ----------------
    name : registry name (``bof``, ``sdf``, ``udf``, ``sals``, ...).
    description : one line for ``--help`` and reports.
    input_kind : ``'points'`` (network input x, 3 values) or ``'segments'`` (u, v: 6 values).
    output_dim : number of network outputs.
    extractor : name of the extraction algorithm, for tables (e.g. ``'marching cubes'``, ``'E-DC'``).
    default_params : extractor parameters and their defaults; users override any of them.
    loss_needs_input_grad : the loss differentiates the network w.r.t. its inputs (the fitting loop
        then sets ``requires_grad`` on each batch's inputs before the forward pass).
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    input_kind: ClassVar[str] = "points"
    output_dim: ClassVar[int] = 1
    extractor: ClassVar[str] = ""
    default_params: ClassVar[dict[str, Any]] = {}
    loss_needs_input_grad: ClassVar[bool] = False

    def __init__(self, **params: Any):
        unknown = set(params) - set(self.default_params)
        if unknown:
            raise ValueError(
                f"method '{self.name}' has no parameter(s) {sorted(unknown)}; known: {sorted(self.default_params)}"
            )
        self.params = {**self.default_params, **params}

    @property
    def input_dim(self) -> int:
        return 3 if self.input_kind == "points" else 6

    # -- training ---------------------------------------------------------------------------
    def network_inputs(self, samples) -> np.ndarray:
        """(M, input_dim) float32 inputs from the shared samples (points, or segments flattened)."""
        if self.input_kind == "points":
            return np.ascontiguousarray(samples.points, dtype=np.float32)
        return np.ascontiguousarray(samples.segments.reshape(len(samples), 6), dtype=np.float32)

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        """Labels for every sample from the exact fields (``benchmark.fields.ExactFields``)."""
        raise NotImplementedError

    def loss(self, prediction, targets: dict, inputs=None, model=None):
        """Scalar torch loss of a batch: ``prediction`` (B, output_dim), ``targets`` torch tensors."""
        raise NotImplementedError

    # -- extraction ---------------------------------------------------------------------------
    def oracle_grid(self, fields, N: int, cache=None) -> tuple[Any, dict[str, float]]:
        """The exact field on the N^3 grid, as :meth:`extract` consumes it, and query timings."""
        raise NotImplementedError

    def neural_grid(self, model, N: int, device) -> tuple[Any, dict[str, float]]:
        """The fitted network's field on the N^3 grid, as :meth:`extract` consumes it, and timings."""
        raise NotImplementedError

    def extract(self, grid_field, N: int, query=None) -> Extraction:
        """Turn the grid field into a mesh (canonical frame). ``query`` optionally evaluates the
        underlying continuous field at arbitrary points (for extractors that re-check vertices)."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "extractor": self.extractor, "input": self.input_kind, "params": dict(self.params)}


_REGISTRY: dict[str, type[Method]] = {}
_LOADED = False


def register_method(cls: type[Method]) -> type[Method]:
    """Class decorator: make a :class:`Method` subclass available under ``cls.name``."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} must set a non-empty 'name'")
    if cls.name in _REGISTRY and _REGISTRY[cls.name] is not cls:
        raise ValueError(f"method name '{cls.name}' is registered twice ({_REGISTRY[cls.name].__name__}, {cls.__name__})")
    _REGISTRY[cls.name] = cls
    return cls


def _load_all() -> None:
    """Import every module of the ``methods`` package once, so each file registers itself."""
    global _LOADED
    if _LOADED:
        return
    import methods

    for info in pkgutil.iter_modules(methods.__path__):
        importlib.import_module(f"methods.{info.name}")
    _LOADED = True


def available_methods() -> list[str]:
    _load_all()
    return sorted(_REGISTRY)


def get_method(name: str, **params: Any) -> Method:
    """Instantiate a registered method; unknown names raise one line listing the known ones."""
    _load_all()
    if name not in _REGISTRY:
        raise ValueError(f"unknown method '{name}'; known methods: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name](**params)
