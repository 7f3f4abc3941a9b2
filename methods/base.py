"""The representation interface and its registry.

A *method* is a representation + surface extraction: what the network predicts (its field), the
exact field it learns from (computed from the mesh), its loss and its extractor. Each method lives in
one file under ``methods/`` and declares itself with :func:`register_method`; the run layer only ever
calls :func:`get_method` and the interface below, so adding a method is adding one file.

Data flow (one way): ``Shape`` -> shared ``Samples`` (foundation.sampler) -> ``Method.training_targets``
(from ``foundation.fields.ExactFields``) -> shared fitting loop (methods.core.fitting) -> ``Method.neural_grid``
or ``Method.oracle_grid`` (the field on the grid the extractor needs) -> ``Method.extract`` ->
``Extraction`` (mesh in the canonical frame).

Timing: the job times the stages ``query`` (around ``oracle_grid``/``neural_grid``) and ``extract``
(around ``extract``); inside them a method names its sub-steps with :func:`foundation.timing.stage`
(``with stage("normals"):`` -> ``query_normals_s``) or :func:`foundation.timing.record` for durations
an extractor returns. Methods never write ``perf_counter`` pairs.
"""

from __future__ import annotations

import importlib
import pkgutil
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterator, Mapping

import numpy as np

from foundation.registry import Registry
from foundation.params import Param, parsed_values
from methods.core.budgets import BUDGET_FAMILIES, BudgetFamily
from methods.core.device import get_device


def median_angle_deg(a: np.ndarray, b: np.ndarray, oriented: bool = False) -> float:
    """Median angle in degrees between the rows of ``a`` and ``b`` (P, 3), over the rows where both
    are non-zero (NaN if none). Unoriented (default, for normals of planes): opposite vectors are 0
    apart, so the angle lies in [0, 90]; ``oriented``: in [0, 180]."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    ok = (na > 0) & (nb > 0)
    if not ok.any():
        return float("nan")
    cos = np.einsum("ij,ij->i", a[ok], b[ok]) / (na[ok] * nb[ok])
    cos = cos if oriented else np.abs(cos)
    return float(np.degrees(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))))


def signed_hybrid(sign_source: np.ndarray, magnitude_source: np.ndarray, level: float) -> np.ndarray:
    """``level + sign(sign_source - level) |magnitude_source - level|``: the side of the level set
    from one field, the distance to it from the other (a grid field's sign/magnitude decomposition;
    with one field for both, that field, exactly for level 0)."""
    side = np.sign(np.asarray(sign_source, dtype=np.float32) - np.float32(level))
    return (np.float32(level) + side * np.abs(np.asarray(magnitude_source, dtype=np.float32) - np.float32(level))).astype(np.float32)


def wrong_side_points(fitted: np.ndarray, exact: np.ndarray, level: float) -> int:
    """Grid points whose fitted value lies on the other side of ``level`` than the exact one."""
    return int(np.count_nonzero(np.sign(np.asarray(fitted) - level) != np.sign(np.asarray(exact) - level)))


@dataclass
class Extraction:
    """A mesh extracted by a method, canonical frame, plus scalar facts about the extraction
    (e.g. the number of intersected edges) recorded with the job."""

    vertices: np.ndarray
    faces: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


class Method:
    """What every method of every task has: a name, parameters, a budget family, availability and a
    training record. A method subclasses the base of its task, which adds that task's hooks:
    :class:`FieldMethod` (``encode``: a field fitted per shape, extracted from a grid) or
    :class:`PointCloudMethod` (``reconstruct``: a mesh from a raw point cloud).

    Class attributes
    ----------------
    name : registry name (``bof``, ``sdf``, ``udf``, ``sals``, ``poisson``, ...).
    description : one line for ``--help`` and reports.
    extractor : name of the extraction algorithm, for tables (e.g. ``'marching cubes'``, ``'E-DC'``).
    parameters : the method's parameters, ``{name: Param(default, help, bounds...)}``; users override
        any of them (``--method-param NAME.PARAM=VALUE``), parsed and checked by :class:`Param`.

    How tables and plots show the method (its order, colour and caption note) is registry metadata
    given to :func:`register_method`, not part of the class.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: What the method's network takes, for a method with one: ``'points'`` (x, 3 values) or
    #: ``'segments'`` (u, v: 6 values).
    input_kind: ClassVar[str] = "points"
    output_dim: ClassVar[int] = 1
    extractor: ClassVar[str] = ""
    parameters: ClassVar[dict[str, Param]] = {}
    #: The benchmark task the method serves: ``'encode'`` (:class:`FieldMethod`) or ``'reconstruct'``
    #: (:class:`PointCloudMethod`). (The ``score`` task's rows are folders of meshes, not methods:
    #: :mod:`tasks.rows`.)
    task: ClassVar[str] = ""
    #: Whether the method needs a network trained across shapes (:class:`LearnedPointCloudMethod`).
    learned: ClassVar[bool] = False
    #: The parts of the grid field an error decomposition may take from the exact field instead of
    #: the fitted network (:meth:`hybrid_grid`; ``run_benchmark.py --decompose``), e.g. SALS's
    #: intersection flags, hit positions s and normals. Empty: the method is not decomposed.
    components: ClassVar[tuple[str, ...]] = ()
    #: The registered method whose fitted network this one extracts, when the two share their field
    #: (the same targets, loss and fit parameters; e.g. ``sdf-ndc`` extracts the ``sdf`` network
    #: with another extractor): its fits are stored and keyed under that name, so one fit serves
    #: both. Empty: the method's own fit.
    fit_of: ClassVar[str] = ""
    #: The name its fitted weights are keyed and stored under: :attr:`fit_of`, else its own (set
    #: for every subclass).
    fit_name: ClassVar[str] = ""
    #: The budget family whose records the method's fit or training reads (:class:`BudgetFamily`;
    #: ``'encode'``: the per-shape fit of :mod:`methods.core.fitting`); None: the method fits and
    #: trains nothing, so no budget applies to it.
    budget_family: ClassVar[str | None] = None

    def __init_subclass__(cls, **kwargs: Any):
        super().__init_subclass__(**kwargs)
        cls.fit_name = cls.fit_of or cls.name

    def __init__(self, **params: Any):
        self.params = parsed_values(self.parameters, params, self.name)

    @classmethod
    def budget_fields(cls) -> frozenset[str]:
        """The budget fields a run may change that this method reads: those of its family."""
        if cls.budget_family is None:
            return frozenset()
        return frozenset(budget_family(cls.budget_family).params)

    @classmethod
    def budget(cls, name: str, overrides: Mapping[str, Any] | None = None):
        """The record named ``name`` of the method's budget family with the ``overrides`` it reads
        applied (typed, range-checked; the others are not this method's and are left out); None for
        a method without a budget family. An unknown name raises with the family's known names."""
        return family_budget(cls.budget_family, name, overrides)

    @classmethod
    def unavailable(cls) -> str | None:
        """Why the method cannot run on this machine (one line, e.g. data it reads is absent), or
        None. Such a method is left out of the default method list and refused when named."""
        return None

    def training_record(self):
        """What the trained weights this method reads were trained on
        (:class:`methods.core.training_record.TrainingRecord`), so each result row can say whether
        its shape was seen in training; None for a method that reads no trained weights. A learned
        point-cloud method's record comes from its training set (the run layer knows it)."""
        return None

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "extractor": self.extractor, "input": self.input_kind, "params": dict(self.params)}


class FieldMethod(Method):
    """A method of the ``encode`` task: a network fitted to one shape from its exact fields (or the
    exact field itself, oracle mode), queried on a grid and extracted to a mesh. Subclasses set
    ``input_kind``, ``output_dim`` and ``extractor`` and implement the hooks below."""

    task: ClassVar[str] = "encode"
    budget_family: ClassVar[str | None] = "encode"

    @property
    def input_dim(self) -> int:
        return 3 if self.input_kind == "points" else 6

    # -- training ---------------------------------------------------------------------------
    def fit_params(self) -> dict:
        """The parameter values the fit reads (``Param(fit=True)``): they key the fitted weights."""
        return {k: v for k, v in self.params.items() if self.parameters[k].fit}

    def network_inputs(self, samples) -> np.ndarray:
        """(M, input_dim) float32 inputs from the shared samples (points, or segments flattened)."""
        if self.input_kind == "points":
            return np.ascontiguousarray(samples.points, dtype=np.float32)
        return np.ascontiguousarray(samples.segments.reshape(len(samples), 6), dtype=np.float32)

    def network_config(self, budget) -> dict:
        """Keyword arguments of :func:`methods.core.network.make_network` for the network this method fits
        under ``budget`` (a :class:`methods.core.fitting.Budget`); default: the budget's backbone,
        ``budget.network_config()``. A method with a network of its own (e.g. NGLOD's) returns it."""
        return budget.network_config()

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        """Labels for every sample from the exact fields (``foundation.fields.ExactFields``)."""
        raise NotImplementedError

    def predict(self, model, inputs):
        """What :meth:`loss` compares with a batch's targets: the network's outputs (B, output_dim)
        (default); a method whose loss needs more of the network (e.g. its input gradient) returns it."""
        return model(inputs)

    def loss(self, prediction, targets: dict):
        """Scalar torch loss of a batch: ``prediction`` from :meth:`predict`, ``targets`` torch tensors."""
        raise NotImplementedError

    # -- extraction ---------------------------------------------------------------------------
    def oracle_grid(self, fields, N: int, cache) -> tuple[Any, dict[str, Any]]:
        """The exact field on the N^3 grid, as :meth:`extract` consumes it, and scalar facts.

        ``cache`` is a :class:`foundation.field_cache.FieldCache` (its directory may be None: off)."""
        raise NotImplementedError

    def neural_grid(self, model, N: int, device) -> tuple[Any, dict[str, Any]]:
        """The fitted network's field on the N^3 grid, as :meth:`extract` consumes it, and scalar
        facts (e.g. ``query_fraction``, the share of the dense queries evaluated)."""
        raise NotImplementedError

    def extract(self, grid_field, N: int) -> Extraction:
        """Turn the grid field into a mesh (canonical frame)."""
        raise NotImplementedError

    def calibrate(self, model, fields, N: int, rng: np.random.Generator, device=None) -> dict[str, Any]:
        """Settle settings of the neural query from the fitted ``model`` and labels of the exact
        ``fields`` (as its training targets are), after the fit and before :meth:`neural_grid`;
        returns scalar facts of the job. Default: nothing to calibrate."""
        return {}

    # -- error decomposition -------------------------------------------------------------------
    @classmethod
    def decompositions(cls) -> list[tuple[str, ...]]:
        """The sets of components a decomposition takes from the exact field: each component alone,
        every component but one (with three or more), and all of them (which must reproduce the
        oracle field exactly); in :attr:`components` order, no repeats, never the empty set (that is
        the fitted field itself)."""
        comps = cls.components
        sets = [(c,) for c in comps]
        if len(comps) >= 3:
            sets += [tuple(d for d in comps if d != c) for c in comps]
        if len(comps) >= 2:
            sets.append(tuple(comps))
        return sets

    def exact_grid(self, fields, N: int, cache):
        """The exact field on the grid as a decomposition takes its components from it (the ``exact``
        of :meth:`hybrid_grid` and :meth:`component_errors`): :meth:`oracle_grid`'s field, unless
        oracle mode extracts something other than the exact components (a learned extractor)."""
        return self.oracle_grid(fields, N, cache)[0]

    def hybrid_grid(self, fitted, exact, exact_parts: tuple[str, ...], model, N: int, device=None):
        """The grid field with the components ``exact_parts`` from ``exact`` (:meth:`oracle_grid`)
        and the others from ``fitted`` (:meth:`neural_grid`) or from ``model`` where ``fitted`` does
        not hold them (e.g. the network's s on an edge only the exact field intersects)."""
        raise NotImplementedError

    def component_errors(self, fitted, exact, N: int) -> dict[str, float]:
        """Errors of the fitted field's components against the exact ones (metric columns)."""
        return {}

    def extraction_data_digest(self) -> str:
        """A digest of the data files (not code) the extraction reads, e.g. trained weights, or ''
        when it reads none: part of the key of its cached meshes, so a changed file never serves a
        mesh extracted with the old one."""
        return ""


class PointCloudMethod(Method):
    """A method of the ``reconstruct`` task: a mesh from a raw point cloud, no normals given.

    Subclasses implement :meth:`reconstruct`; classic (non-learned) methods need nothing else. A
    method that optimises something per shape under a budget of its own sets ``budget_family``; the
    job then passes its record as ``reconstruct(..., budget=record)``. The
    job samples the point cloud (``foundation.surface.sample_surface`` with the job's sampler
    stream, the same cloud for every method of a (shape, seed)) and times ``reconstruct`` as the
    ``reconstruct`` stage (sub-steps via :func:`foundation.timing.stage`).
    """

    task: ClassVar[str] = "reconstruct"
    input_kind: ClassVar[str] = "points"
    budget_family: ClassVar[str | None] = None
    #: Whether :meth:`reconstruct` takes ``sensors=`` ((P, 3) float64: the position, canonical frame,
    #: of the sensor that saw each point) and uses it. The job passes it only when the input cloud
    #: carries sensors (a scan), and records in the job's row whether it did (``used_sensors``).
    uses_sensors: ClassVar[bool] = False

    def checked_points(self, points) -> np.ndarray:
        """``points`` as a float64 (P, 3) array with P >= 1; otherwise a ValueError naming the method."""
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"{self.name} needs a (P, 3) point cloud, got shape {points.shape}")
        if len(points) == 0:
            raise ValueError(f"{self.name}: the point cloud has no points")
        return points

    def reconstruct(self, points: np.ndarray, N: int, device=None, seed: int = 0) -> Extraction:
        """A mesh (canonical frame) from ``points`` (P, 3) float64 in the canonical frame; ``N`` is
        the run's grid resolution (methods with their own resolution rule derive it from N); ``seed``
        is the job's seed (a method that optimises or draws anything per shape seeds it from it). A
        method with ``uses_sensors`` also accepts ``sensors=None``: (P, 3) sensor positions."""
        raise NotImplementedError


class LearnedPointCloudMethod(PointCloudMethod):
    """A learned method of the ``reconstruct`` task: a network trained once across many shapes (the
    run layer caches it per training set, method, budget and code), then applied to a test cloud.

    :class:`methods.pointcloud.knn.method.KNNTrainedMethod` trains the shared K-NN local network
    (:mod:`methods.pointcloud.knn.network`). Its class attributes: ``network_kind`` ``'segment'`` (the network takes a
    segment (u, v) and the K nearest input points of its midpoint) or ``'point'`` (a point x and its K
    nearest input points); ``output_dim`` its outputs. Training samples and labels come from the
    shared sampler and the exact fields of each training shape, as for the encoding methods
    (:meth:`training_targets`; ``segments`` or ``points`` of :class:`foundation.sampler.Samples` by
    ``network_kind``), the loss from :meth:`loss` (``prediction`` (B, output_dim) logits/values,
    ``targets`` torch tensors).

    Every learned method names its budget family (``budget_family``), whose records carry the
    training set's fields. A method with its own architecture and training implements :meth:`train_network`,
    :meth:`network_to_bytes` and :meth:`network_from_bytes` (or subclasses
    :class:`methods.pointcloud.own_network.OwnNetworkMethod`, which stores its config with the weights), and
    names the modules of its training code in ``training_modules`` (part of the weights' cache key,
    with the method's own module).
    """

    learned: ClassVar[bool] = True
    network_kind: ClassVar[str] = "point"
    #: Modules (besides the method's own) whose code the trained network depends on.
    training_modules: ClassVar[tuple[str, ...]] = ()

    def training_cloud_points(self, budget) -> int:
        """Points of each training cloud the network saw under ``budget`` (the density a scene's
        cloud is matched to, :func:`methods.pointcloud.blocks.density_scale`)."""
        return int(budget.points_per_item)

    def train_network(self, shapes: list, budget, seed: int, device=None, progress=None):
        """Train this method's network on ``shapes`` (:class:`datasets.Shape`) under ``budget`` (a
        record of its budget family, with the :class:`methods.pointcloud.training_set.TrainingSet`
        fields) from ``seed``; ``progress(step=..., loss=..., total=...)`` now and then (``total``:
        the step count). Returns an object with ``model`` (eval mode), ``steps``, ``seconds`` (the
        step loop), ``samples_per_s`` and ``final_loss``."""
        raise NotImplementedError

    def network_to_bytes(self, trained, budget) -> bytes:
        """The bytes the run layer stores (checksummed) for ``trained`` (:meth:`train_network`'s result)."""
        raise NotImplementedError

    def network_from_bytes(self, data: bytes, device=None):
        """The model (eval mode, on ``device``) of :meth:`network_to_bytes`' bytes."""
        raise NotImplementedError

    def training_targets(self, fields, samples) -> dict[str, np.ndarray]:
        """Labels for every training sample from the exact fields of a training shape."""
        raise NotImplementedError

    def loss(self, prediction, targets: dict):
        """Scalar torch loss of a training batch (``prediction`` the network's outputs)."""
        raise NotImplementedError

    def reconstruct(self, points: np.ndarray, N: int, device=None, seed: int = 0, model=None) -> Extraction:
        """A mesh from ``points`` with the trained ``model`` (eval mode; required)."""
        raise NotImplementedError

    def network_on_device(self, model, device=None):
        """(``model`` in eval mode on the chosen device, that device); a ValueError naming the method
        when no trained model is given."""
        if model is None:
            raise ValueError(f"{self.name} reconstructs with a trained network: none given")
        device = get_device(device)
        return model.to(device).eval(), device


def _import_method_modules() -> None:
    """Import every module of the ``methods`` package and its sub-packages once, so each file
    registers itself."""
    import methods

    for info in pkgutil.walk_packages(methods.__path__, prefix="methods."):
        importlib.import_module(info.name)


#: The method registry: name -> Method subclass, listed in display order.
METHODS: Registry[type[Method]] = Registry("method", loader=_import_method_modules,
                                           order=lambda cls: (PRESENTATION.get(cls.name, Presentation()).order,
                                                              cls.name))


@dataclass(frozen=True)
class Presentation:
    """How tables, plots and the default method list show a method: registry metadata beside its
    class, not part of its algorithm (code digests leave it out).

    order : position in tables, plots and the default ``--methods`` list (low first).
    color : hex colour of the method in the report's plots.
    note : a sentence every table caption of a run with the method carries, where its row could be
        mistaken for something else (e.g. an ablation named after a published family).
    """

    order: int = 100
    color: str = "#7f7f7f"
    note: str = ""


#: The presentation of each registered method, by name (:func:`register_method`).
PRESENTATION: dict[str, Presentation] = {}


def register_method(cls: type[Method] | None = None, /, *, order: int = 100, color: str = "#7f7f7f",
                    note: str = ""):
    """Class decorator: make a :class:`Method` subclass available under ``cls.name``, shown with
    ``order``, ``color`` and ``note`` (:class:`Presentation`). Used bare as a decorator it gives the
    defaults; ``register_method(cls, order=...)`` registers a class directly."""
    def register(cls: type[Method]) -> type[Method]:
        if not cls.name:
            raise ValueError(f"{cls.__name__} must set a non-empty 'name'")
        METHODS.register(cls.name, cls)
        PRESENTATION[cls.name] = Presentation(order, color, note)
        return cls

    return register if cls is None else register(cls)


@contextmanager
def registered_method(cls: type[Method], **presentation: Any) -> Iterator[type[Method]]:
    """Register ``cls`` with its :class:`Presentation` fields for the duration of a ``with`` block
    (tests, plugins tried out)."""
    with METHODS.registered(cls.name, cls):
        PRESENTATION[cls.name] = Presentation(**presentation)
        try:
            yield cls
        finally:
            PRESENTATION.pop(cls.name, None)


def presentation(name: str) -> Presentation:
    """How method ``name`` is shown (the defaults for a name registered without one)."""
    METHODS.names()
    return PRESENTATION.get(name, Presentation())


def budget_family(name: str) -> BudgetFamily:
    """The budget family ``name``, once every method module is imported (each family is registered
    by the module that defines its record type)."""
    METHODS.names()
    return BUDGET_FAMILIES.get(name)


def family_budget(family: str | None, name: str, overrides: Mapping[str, Any] | None = None):
    """The record named ``name`` of budget family ``family`` with the ``overrides`` among its fields
    applied (typed, range-checked; the others are left out); None for no family."""
    if family is None:
        return None
    fields = budget_family(family).params
    return budget_family(family).get(name, {k: v for k, v in (overrides or {}).items() if k in fields})


def available_methods(task: str | None = "encode") -> list[str]:
    """Registered method names of one task (None: every task) that can run on this machine
    (:meth:`Method.unavailable`), in display order."""
    return [m for m in METHODS.names() if (task is None or METHODS.get(m).task == task)
            and METHODS.get(m).unavailable() is None]


def get_method(name: str, **params: Any) -> Method:
    """Instantiate a registered method with checked parameters (unknown names list the known ones)."""
    return METHODS.get(name)(**params)
