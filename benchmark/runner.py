"""The benchmark runner: configuration, the job list, THE job function, and the driver.

    python run_benchmark.py --methods sals sdf --mode oracle --grid 64
    python run_benchmark.py report runs/20250101-120000 [runs/... ...]

A run is ``shapes x methods x seeds`` jobs plus one *floor* task per shape (the GT scored against a
resample of itself, ``benchmark.metrics.floor``; it also exports ``meshes/<shape>/gt.ply``).

* :class:`JobSpec` / :class:`FloorSpec` are plain picklable descriptions; :func:`run_job` and
  :func:`run_floor` load the shape themselves, so any executor (``benchmark.executors``: local,
  process, ray) can run them anywhere. They never raise: any exception becomes a failed
  :class:`JobResult` with a one-line error (and the traceback in its own field).
* The job function never branches on method names: everything method-specific goes through the
  :class:`methods.base.Method` interface.
* The driver (:func:`run`) is the only writer of the run directory: it commits each result to
  ``results.db`` (:mod:`benchmark.records`) as it arrives, writes the returned mesh bytes to
  ``meshes/<shape>/<method>.ply``, then ``results.csv`` and the reports.
* Resume: a job whose ``config_hash`` already has an ``ok`` row is skipped; failed jobs run again.

Caches (reused across runs; root ``$SALSBENCH_CACHE`` or ``~/.cache/salsbench``; ``--no-cache`` off):
``fields/`` exact grid fields (``benchmark.fields.cached_grid_fields``), ``weights/`` fitted
networks keyed by (shape hash, method's network identity, budget, seed, sampler/fitting code),
``meshes/`` extracted meshes keyed by (weights key or exact-field version, method params, grid,
extraction code). Code keys are SHA-256 digests of the source files involved, so editing an
extractor never serves a stale mesh.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as _dt
import hashlib
import importlib
import inspect
import io
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
import traceback as _traceback
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

REPO = Path(__file__).resolve().parents[1]

#: Defaults of the command line (SPEC values; ``eval_points`` see :data:`DEFAULT_EVAL_POINTS`).
DEFAULT_DATASET = "builtin"
DEFAULT_MODE = "neural"
DEFAULT_BUDGET = "quick"
DEFAULT_GRID = 128
DEFAULT_PRESET = "default"
DEFAULT_SEEDS = (0,)
DEFAULT_EXECUTOR = "local"
DEFAULT_RETRIES = 1
#: Surface samples per mesh for the metrics when ``--eval-points`` is not given: the preset's own n
#: (1,000,000 for ``default``, SPEC section 7). Every table caption states the n used.
DEFAULT_EVAL_POINTS = None

MODES = ("neural", "oracle")
EXECUTORS = ("local", "process", "ray")
MIN_GRID = 8
MIN_EVAL_POINTS = 1000

#: Columns of results.csv, in this order (a contract: tests and users read them); every other
#: metric/timing column follows.
RESULT_COLUMNS = (
    "shape", "method", "mode", "seed", "status", "error", "cd", "nc", "f1_005", "f1_01", "ecd", "ef1",
    "n_vertices", "n_faces", "boundary_edges", "nonmanifold_edges", "components",
    "fit_s", "query_s", "extract_s", "metrics_s",
)

#: Packages whose versions go into config.json and every job row.
VERSION_PACKAGES = ("numpy", "torch", "trimesh", "scikit-image", "libigl", "scipy", "pandas", "embreex",
                    "manifold3d", "pykdtree", "ray")


class ConfigError(ValueError):
    """A bad option, path or name on the command line: one line, reported before any work starts."""


# =============================================================================================
# Job descriptions and results
# =============================================================================================


@dataclass(frozen=True)
class JobSpec:
    """One (shape, method, seed) job; picklable, self-contained.

    dataset, dataset_options : how to build the dataset (``datasets.get_dataset``) in the worker.
    shape : shape name within the dataset.
    method, params : registry name and extractor parameters (``methods.base.get_method``).
    mode : 'neural' (fit a network, extract from it) or 'oracle' (extract from the exact field).
    budget : fitting budget name (``methods.fitting``); unused in oracle mode.
    grid : N, grid points per axis. eval_points : metric samples per mesh (None: preset's n).
    metric_preset : ``benchmark.metrics.PRESETS`` name. seed : sampler/fitting/metric seed.
    cache_dir : cache root (None: caches off). plugins : modules imported first (extra methods).
    threads : torch threads in the worker (None: leave as is). device : torch device (None: auto).
    """

    dataset: str
    dataset_options: dict
    shape: str
    method: str
    params: dict
    mode: str
    budget: str
    grid: int
    eval_points: int | None
    metric_preset: str
    seed: int
    cache_dir: str | None = None
    plugins: tuple[str, ...] = ()
    threads: int | None = None
    device: str | None = None

    kind = "job"

    def identity(self) -> dict:
        """Everything that defines the job's result (the config hash is its digest)."""
        return {
            "dataset": self.dataset, "dataset_options": identity_options(self.dataset_options),
            "shape": self.shape, "method": self.method, "params": self.params, "mode": self.mode,
            "budget": self.budget if self.mode == "neural" else None, "grid": self.grid,
            "eval_points": self.eval_points, "metric_preset": self.metric_preset, "seed": self.seed,
        }

    @property
    def key(self) -> str:
        return digest(self.identity())

    @property
    def uses_fitting(self) -> bool:
        """True when the job trains a network (asks an executor for a GPU when there is one)."""
        return self.mode == "neural"

    @property
    def label(self) -> str:
        return f"{self.shape}/{self.method}/s{self.seed}"


@dataclass(frozen=True)
class FloorSpec:
    """The floor task of one shape: GT vs a resample of itself; also exports the GT mesh."""

    dataset: str
    dataset_options: dict
    shape: str
    eval_points: int | None
    metric_preset: str
    seed: int
    plugins: tuple[str, ...] = ()
    threads: int | None = None

    kind = "floor"
    uses_fitting = False

    def identity(self) -> dict:
        return {
            "floor": True, "dataset": self.dataset, "dataset_options": identity_options(self.dataset_options),
            "shape": self.shape, "eval_points": self.eval_points, "metric_preset": self.metric_preset,
            "seed": self.seed,
        }

    @property
    def key(self) -> str:
        return digest(self.identity())

    @property
    def label(self) -> str:
        return f"{self.shape}/floor"


@dataclass
class JobResult:
    """What a job returns to the driver (picklable; the mesh travels as PLY bytes).

    status : 'ok' or 'failed'; error : one line (stage: ExceptionType: message); traceback : full text.
    metrics : ``benchmark.metrics.evaluate`` result (raw units; nested 'seconds' removed).
    timings : wall-clock seconds per stage: load_s, sample_s, label_s, fit_s, query_s,
        extract_<step>_s, extract_s (their sum), metrics_s, total_s (and what the method adds).
    """

    kind: str
    key: str
    spec: Any
    status: str = "failed"
    error: str | None = None
    traceback: str | None = None
    metrics: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    fit_loss: float | None = None
    shape_hash: str | None = None
    shape_kind: str | None = None
    shape_info: dict = field(default_factory=dict)
    mesh_ply: bytes | None = None
    cache: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
    device: str | None = None
    host: str | None = None
    versions: dict = field(default_factory=dict)
    started: str | None = None
    finished: str | None = None
    attempts: int = 1

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def identity_options(options: dict) -> dict:
    """Dataset options that change which mesh a shape name denotes (not limit/list_file)."""
    return {k: v for k, v in sorted(options.items()) if k not in ("limit", "list_file")}


def digest(obj: Any) -> str:
    """SHA-256 (hex, 16 chars) of a JSON-able object with sorted keys."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def one_line(exc: BaseException, stage: str | None = None) -> str:
    """``stage: Type: first line of message`` (at most 400 characters)."""
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    text = f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
    if stage:
        text = f"{stage}: {text}"
    return text if len(text) <= 400 else text[:397] + "..."


# =============================================================================================
# Worker-side helpers (imported lazily so the driver and the CLI stay light)
# =============================================================================================


def import_plugins(plugins: Iterable[str]) -> None:
    """Import each plugin: ``module`` (registers on import) or ``module:function`` (then calls it)."""
    for name in plugins:
        module, _, func = name.partition(":")
        mod = importlib.import_module(module)
        if func:
            getattr(mod, func)()


@lru_cache(maxsize=8)
def _dataset_cached(name: str, options_json: str):
    from datasets import get_dataset

    return get_dataset(name, **json.loads(options_json))


def load_dataset(name: str, options: dict):
    return _dataset_cached(name, json.dumps(options, sort_keys=True))


@lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """Installed versions of :data:`VERSION_PACKAGES` (absent ones omitted), plus python."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for name in VERSION_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out


def cache_root(explicit: str | os.PathLike | None = None) -> Path:
    """Cache root: ``explicit``, else ``$SALSBENCH_CACHE``, else ``~/.cache/salsbench``."""
    if explicit:
        return Path(explicit).expanduser()
    env = os.environ.get("SALSBENCH_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "salsbench"


@lru_cache(maxsize=None)
def source_digest(*paths: str) -> str:
    """SHA-256 (16 hex) of the given source files' bytes (missing files count as empty)."""
    h = hashlib.sha256()
    for p in paths:
        path = Path(p)
        h.update(str(path.name).encode())
        if path.is_file():
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _module_file(obj) -> str:
    try:
        return inspect.getsourcefile(obj) or ""
    except TypeError:
        return ""


def fitting_code_key(method) -> str:
    """Digest of the code a fit depends on: sampler, exact fields, network, fitting, the method file."""
    files = [REPO / "benchmark" / "sampler.py", REPO / "benchmark" / "fields.py", REPO / "methods" / "network.py",
             REPO / "methods" / "fitting.py", REPO / "methods" / "base.py", _module_file(type(method))]
    return source_digest(*map(str, files))


def extraction_code_key(method) -> str:
    """Digest of the code an extraction depends on: every methods/*.py, grid and fields."""
    files = sorted(str(p) for p in (REPO / "methods").glob("*.py"))
    files += [str(REPO / "benchmark" / "grid.py"), str(REPO / "benchmark" / "fields.py"), _module_file(type(method))]
    return source_digest(*files)


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def mesh_to_ply(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary PLY bytes of a triangle mesh (no processing, no merging)."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64),
                           process=False, validate=False)
    return mesh.export(file_type="ply", encoding="binary")


def _npz_bytes(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


# -- fitting adapter (methods.fitting) ----------------------------------------------------------


def get_budget(name: str):
    """The fitting budget called ``name`` (``methods.fitting.BUDGETS``; ValueError lists the known ones)."""
    from methods import fitting

    return fitting.get_budget(name)


def budget_names() -> list[str]:
    try:
        from methods import fitting

        return list(getattr(fitting, "BUDGETS"))
    except Exception:  # fitting module not importable: validation reports it
        return ["tiny", "quick", "paper"]


def budget_record(budget) -> dict:
    if dataclasses.is_dataclass(budget):
        return dataclasses.asdict(budget)
    if isinstance(budget, dict):
        return dict(budget)
    return {"repr": repr(budget)}


def budget_samples(budget) -> int:
    """M, the number of training samples the budget draws."""
    for key in ("samples", "n_samples", "num_samples", "total_samples"):
        value = budget.get(key) if isinstance(budget, dict) else getattr(budget, key, None)
        if value is not None:
            return int(value)
    raise AttributeError(f"budget {budget!r} states no sample count")


# =============================================================================================
# The job functions
# =============================================================================================


class _Stages:
    """Stage reporting + timing inside a job."""

    def __init__(self, progress: Callable | None):
        self.progress = progress
        self.stage = "starting"
        self.timings: dict[str, float] = {}

    def enter(self, stage: str, **info) -> None:
        self.stage = stage
        self.report(stage, **info)

    def report(self, stage: str, **info) -> None:
        if self.progress is not None:
            try:
                self.progress(stage, **info)
            except Exception:  # progress display must never fail a job
                pass


def _set_threads(threads: int | None) -> None:
    if threads:
        import torch

        if torch.get_num_threads() != threads:
            torch.set_num_threads(int(threads))


def _new_task(kind: str, spec, progress) -> tuple["JobResult", "_Stages"]:
    """An empty result and a stage tracker for a job or floor task."""
    return JobResult(kind=kind, key=spec.key, spec=spec, started=now_iso(), host=socket.gethostname()), _Stages(progress)


def _prepare_worker(spec, result: "JobResult", st: "_Stages") -> None:
    """The 'loading' stage's set-up in whichever process runs the task: plugins, torch threads, versions."""
    st.enter("loading")
    import_plugins(spec.plugins)
    _set_threads(spec.threads)
    result.versions = package_versions()


def run_job(spec: JobSpec, progress: Callable[..., None] | None = None) -> JobResult:
    """Run one job end to end; never raises (a failure is a failed JobResult with its error).

    Stages: load the shape; (neural) sample (``benchmark.sampler``), label
    (``method.training_targets`` on ``benchmark.fields.ExactFields``), fit (``methods.fitting``)
    and query the network on the grid (``method.neural_grid``); (oracle) read the exact field on the
    grid (``method.oracle_grid``); extract (``method.extract``); score (``benchmark.metrics.evaluate``
    against the GT in the canonical frame). ``progress(stage, **info)`` is called at each stage and
    with ``loss=...`` during fitting.
    """
    t_total = time.perf_counter()
    result, st = _new_task("job", spec, progress)
    try:
        _prepare_worker(spec, result, st)
        from methods.base import get_method

        method = get_method(spec.method, **spec.params)
        t = time.perf_counter()
        shape = load_dataset(spec.dataset, spec.dataset_options).load(spec.shape)
        st.timings["load_s"] = time.perf_counter() - t
        result.shape_hash, result.shape_kind = shape.content_hash, shape.kind
        V, F = shape.vertices, shape.faces

        cache = cache_root(spec.cache_dir) if spec.cache_dir is not None else None
        mesh_cache_path = None
        weights_key = None
        if spec.mode == "neural":
            budget = get_budget(spec.budget)
            weights_key = digest({
                "shape": result.shape_hash, "method": spec.method, "input": method.input_kind,
                "output_dim": method.output_dim, "budget": budget_record(budget), "seed": spec.seed,
                "code": fitting_code_key(method),
            })
        if cache is not None:
            mesh_key = digest({
                "shape": result.shape_hash, "method": spec.method, "params": method.params, "mode": spec.mode,
                "grid": spec.grid, "weights": weights_key, "code": extraction_code_key(method),
            })
            mesh_cache_path = cache / "meshes" / f"{spec.method}_{mesh_key}.npz"

        extraction = _load_cached_mesh(mesh_cache_path)
        if extraction is not None:
            pred_V, pred_F, cached_timings, cached_info, fit_loss = extraction
            st.timings.update(cached_timings)
            result.info.update(cached_info)
            result.fit_loss = fit_loss
            result.cache.append("mesh")
        else:
            pred_V, pred_F, stage_timings, info = _fit_and_extract(spec, method, shape, cache, weights_key, st, result)
            st.timings.update(stage_timings)
            result.info.update(info)
            if mesh_cache_path is not None:
                keep = {k: v for k, v in st.timings.items() if k != "load_s"}
                _atomic_write(mesh_cache_path, _npz_bytes(
                    vertices=pred_V, faces=pred_F, timings=json.dumps(keep), info=json.dumps(result.info, default=str),
                    fit_loss=np.float64(np.nan if result.fit_loss is None else result.fit_loss)))

        st.enter("scoring")
        from benchmark import metrics as _metrics

        t = time.perf_counter()
        scores = _metrics.evaluate(V, F, pred_V, pred_F, preset=spec.metric_preset, seed=spec.seed,
                                   n_points=spec.eval_points)
        st.timings["metrics_s"] = time.perf_counter() - t
        scores.pop("seconds", None)
        result.metrics = scores
        st.enter("saving")
        result.mesh_ply = mesh_to_ply(pred_V, pred_F)
        result.status = "ok"
    except Exception as exc:  # noqa: BLE001 -- every failure becomes a failed row, the run goes on
        result.status = "failed"
        result.error = one_line(exc, st.stage)
        result.traceback = _traceback.format_exc()
    st.timings["total_s"] = time.perf_counter() - t_total
    result.timings = st.timings
    result.finished = now_iso()
    try:
        from methods.device import describe_device, get_device

        result.device = describe_device(get_device(spec.device))
    except Exception:  # noqa: BLE001
        result.device = None
    return result


def _load_cached_mesh(path: Path | None):
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path) as z:
            loss = float(z["fit_loss"])
            return (np.asarray(z["vertices"]), np.asarray(z["faces"]), json.loads(str(z["timings"])),
                    json.loads(str(z["info"])), None if np.isnan(loss) else loss)
    except Exception:  # noqa: BLE001 -- a corrupt cache entry is recomputed
        return None


def _fit_and_extract(spec: JobSpec, method, shape, cache: Path | None, weights_key: str | None,
                     st: _Stages, result: JobResult):
    """Neural: sample, label, fit (or load cached weights), query; oracle: exact grid field. Then extract."""
    from benchmark.fields import ExactFields

    timings: dict[str, float] = {}
    V, F = shape.vertices, shape.faces
    if spec.mode == "oracle":
        st.enter("querying")
        fields = ExactFields(V, F)
        if cache is not None:
            grid_field, query_timings = method.oracle_grid(fields, spec.grid, cache=str(cache / "fields"))
        else:  # caches off: a private directory, so no field is read from or left in a shared cache
            with tempfile.TemporaryDirectory(prefix="salsbench-fields-") as private:
                grid_field, query_timings = method.oracle_grid(fields, spec.grid, cache=private)
        timings.update(query_timings or {})
    else:
        from methods.device import get_device

        device = get_device(spec.device)
        model = None
        weights_path = cache / "weights" / f"{spec.method}_{weights_key}.pt" if cache is not None else None
        if weights_path is not None and weights_path.is_file():
            model, result.fit_loss = _load_weights(weights_path, method, spec, device)
            if model is not None:
                result.cache.append("weights")
        if model is None:
            from benchmark.sampler import sample_training_data

            budget = get_budget(spec.budget)
            st.enter("sampling")
            t = time.perf_counter()
            samples = sample_training_data(V, F, budget_samples(budget), spec.seed, shape_hash=result.shape_hash)
            timings["sample_s"] = time.perf_counter() - t
            st.enter("labelling")
            t = time.perf_counter()
            fields = ExactFields(V, F)
            targets = method.training_targets(fields, samples)
            timings["label_s"] = time.perf_counter() - t
            st.enter("fitting")
            t = time.perf_counter()
            model, result.fit_loss, fit_info = _fit(method, samples, targets, budget, spec.seed, device, st)
            timings["fit_s"] = time.perf_counter() - t
            result.info.update(fit_info)
            if weights_path is not None:
                _save_weights(weights_path, model, budget, method, result.fit_loss)
        st.enter("querying")
        grid_field, query_timings = method.neural_grid(model, spec.grid, device)
        timings.update(query_timings or {})
    st.enter("extracting")
    t = time.perf_counter()
    extraction = method.extract(grid_field, spec.grid)
    elapsed = time.perf_counter() - t
    ext_timings = {k: float(v) for k, v in (extraction.timings or {}).items()}
    timings.update(ext_timings)
    if "extract_s" not in ext_timings:
        steps = [v for k, v in ext_timings.items() if k.startswith("extract_")]
        timings["extract_s"] = float(sum(steps)) if steps else elapsed
    info = {k: v for k, v in (extraction.info or {}).items() if isinstance(v, (int, float, str, bool))}
    return np.asarray(extraction.vertices, dtype=np.float64), np.asarray(extraction.faces, dtype=np.int64), timings, info


def _fit(method, samples, targets, budget, seed, device, st: _Stages):
    """Fit the method's network with ``methods.fitting.fit``; (model, final loss, info).

    A non-finite final loss raises (the job is recorded failed with 'non-finite loss')."""
    from methods import fitting

    def on_loss(step=None, loss=None, **_):
        st.report("fitting", step=step, loss=loss)

    kwargs = {"seed": seed, "device": device}
    params = inspect.signature(fitting.fit).parameters
    for name in ("progress", "callback", "on_step"):
        if name in params:
            kwargs[name] = on_loss
            break
    out = fitting.fit(method, samples, targets, budget, **kwargs)
    model = getattr(out, "model", out)
    loss = getattr(out, "final_loss", None)
    if loss is None:
        loss = getattr(out, "loss", None)
    loss = None if loss is None else float(loss)
    if loss is not None and not np.isfinite(loss):
        raise FloatingPointError(f"non-finite training loss ({loss})")
    info = {}
    for key in ("steps", "seconds", "samples_per_s"):
        value = getattr(out, key, None)
        if isinstance(value, (int, float)):
            info[f"fit_{key}"] = value
    return model, loss, info


def _save_weights(path: Path, model, budget, method, loss) -> None:
    from methods import fitting

    fitting.save_model(path, model, budget, method.name, extra={"loss": loss})


def _load_weights(path: Path, method, spec: JobSpec, device):
    """(model, loss) from the weights cache, or (None, None) when unusable (it is then refitted)."""
    try:
        from methods import fitting

        model, blob = fitting.load_model(path, device=device, method_name=method.name)
        return model, blob.get("loss")
    except Exception:  # noqa: BLE001 -- a stale/corrupt entry is refitted
        return None, None


def run_floor(spec: FloorSpec, progress: Callable[..., None] | None = None) -> JobResult:
    """The floor of one shape (``benchmark.metrics.floor``) and its GT mesh as PLY bytes; never raises."""
    t_total = time.perf_counter()
    result, st = _new_task("floor", spec, progress)
    try:
        _prepare_worker(spec, result, st)
        t = time.perf_counter()
        shape = load_dataset(spec.dataset, spec.dataset_options).load(spec.shape)
        st.timings["load_s"] = time.perf_counter() - t
        result.shape_hash, result.shape_kind = shape.content_hash, shape.kind
        result.shape_info = {"source": str(shape.source), "gt_vertices": int(len(shape.vertices)),
                             "gt_faces": int(len(shape.faces))}
        st.enter("scoring floor")
        from benchmark import metrics as _metrics

        t = time.perf_counter()
        scores = _metrics.floor(shape.vertices, shape.faces, preset=spec.metric_preset, seed=spec.seed,
                                n_points=spec.eval_points)
        st.timings["metrics_s"] = time.perf_counter() - t
        scores.pop("seconds", None)
        result.metrics = scores
        result.mesh_ply = mesh_to_ply(shape.vertices, shape.faces)
        result.status = "ok"
    except Exception as exc:  # noqa: BLE001
        result.status = "failed"
        result.error = one_line(exc, st.stage)
        result.traceback = _traceback.format_exc()
    st.timings["total_s"] = time.perf_counter() - t_total
    result.timings = st.timings
    result.finished = now_iso()
    return result


def run_task(spec, progress: Callable[..., None] | None = None) -> JobResult:
    """Dispatch on the spec's type (job or floor): the single entry point every executor calls."""
    if isinstance(spec, FloorSpec):
        return run_floor(spec, progress)
    return run_job(spec, progress)


# =============================================================================================
# Configuration
# =============================================================================================


def parse_method_params(items: Sequence[str] | None) -> dict[str, dict[str, Any]]:
    """``['sals.o_threshold=0.2', 'udf.faces=quad2']`` -> ``{'sals': {'o_threshold': 0.2}, ...}``.

    Values are read as JSON when possible (numbers, true/false, null, lists), else kept as strings.
    """
    out: dict[str, dict[str, Any]] = {}
    for item in items or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise ConfigError(f"--method-param '{item}': use METHOD.NAME=VALUE (e.g. sals.o_threshold=0.2)")
        lhs, raw = item.split("=", 1)
        method, name = lhs.split(".", 1)
        if not method or not name:
            raise ConfigError(f"--method-param '{item}': use METHOD.NAME=VALUE (e.g. sals.o_threshold=0.2)")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        out.setdefault(method, {})[name] = value
    return out


#: Config keys that define a run's protocol: a run directory holds one protocol (adding methods,
#: shapes or seeds to it is fine).
PROTOCOL_KEYS = ("dataset", "data_dir", "mode", "budget", "grid", "eval_points", "metric_preset", "method_params")


def _existing_path(flag: str, value, kind: str) -> str:
    """The absolute path of an existing directory/file given to ``flag``; ConfigError naming it otherwise."""
    path = Path(value).expanduser()
    if not (path.is_dir() if kind == "directory" else path.is_file()):
        raise ConfigError(f"{flag} {value}: {'not a ' + kind if path.exists() else 'does not exist'}")
    return str(path.resolve())


def resolve_config(args: argparse.Namespace) -> dict:
    """Validate the parsed options and return the resolved configuration (no work done yet).

    Raises :class:`ConfigError` with one line naming the problem.
    """
    given = {k: v for k, v in vars(args).items() if v is not None}
    out_dir = given.get("out")
    saved = None
    if given.get("resume"):
        if out_dir is None:
            out_dir = latest_run_dir()
            if out_dir is None:
                raise ConfigError("--resume: no --out given and no earlier run under runs/")
        cfg_path = Path(out_dir) / "config.json"
        if not cfg_path.is_file():
            raise ConfigError(f"--resume: {cfg_path} does not exist (nothing to resume)")
        saved = json.loads(cfg_path.read_text())
    cfg: dict[str, Any] = {}
    fallback = saved.get("options", {}) if saved else {}

    def pick(name, default):
        if name in given:
            return given[name]
        value = fallback.get(name)
        return default if value is None else value

    import_plugins_safe(pick("plugin", []) or [])
    cfg["plugins"] = list(pick("plugin", []) or [])

    # methods
    from methods.base import available_methods, get_method

    known = available_methods()
    methods = list(dict.fromkeys(pick("methods", None) or default_methods(known)))
    for m in methods:
        if m not in known:
            raise ConfigError(f"unknown method '{m}'; known methods: {', '.join(known)}")
    params = parse_method_params(pick("method_param", []))
    for m in params:
        if m not in methods:
            raise ConfigError(f"--method-param names method '{m}', which is not in --methods ({', '.join(methods)})")
    resolved_params = {}
    for m in methods:
        try:
            resolved_params[m] = get_method(m, **params.get(m, {})).params
        except (ValueError, TypeError) as exc:
            raise ConfigError(str(exc).splitlines()[0]) from None
    cfg["methods"] = methods
    cfg["method_param"] = [f"{m}.{k}={json.dumps(v)}" for m, kv in params.items() for k, v in kv.items()]
    cfg["method_params"] = {m: params.get(m, {}) for m in methods}
    cfg["method_params_resolved"] = resolved_params

    # scalar options
    mode = pick("mode", DEFAULT_MODE)
    if mode not in MODES:
        raise ConfigError(f"--mode must be one of {', '.join(MODES)}, got '{mode}'")
    budget = pick("budget", DEFAULT_BUDGET)
    if mode == "neural":
        try:
            budget_obj = get_budget(budget)
        except (ImportError, AttributeError) as exc:
            raise ConfigError(f"neural mode needs methods.fitting ({one_line(exc)}); use --mode oracle") from None
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        cfg["budget_resolved"] = budget_record(budget_obj)
    else:
        budget = None  # oracle mode fits nothing: no budget in the protocol or the tables
    grid = int(pick("grid", DEFAULT_GRID))
    if grid < MIN_GRID:
        raise ConfigError(f"--grid must be >= {MIN_GRID} points per axis, got {grid}")
    from benchmark.metrics import PRESETS

    preset = pick("metric_preset", DEFAULT_PRESET)
    if preset not in PRESETS:
        raise ConfigError(f"--metric-preset must be one of {', '.join(PRESETS)}, got '{preset}'")
    eval_points = pick("eval_points", DEFAULT_EVAL_POINTS)
    if eval_points is not None and int(eval_points) < MIN_EVAL_POINTS:
        raise ConfigError(f"--eval-points must be >= {MIN_EVAL_POINTS}, got {eval_points}")
    seeds = list(dict.fromkeys(int(s) for s in (pick("seed", None) or DEFAULT_SEEDS)))
    if any(s < 0 for s in seeds):
        raise ConfigError(f"--seed values must be >= 0, got {seeds}")
    cfg.update(mode=mode, budget=budget, grid=grid, metric_preset=preset,
               eval_points=None if eval_points is None else int(eval_points),
               eval_points_effective=int(eval_points) if eval_points is not None else PRESETS[preset].n_points,
               metric_protocol=PRESETS[preset].describe(), seeds=seeds)

    # executor
    executor = pick("executor", DEFAULT_EXECUTOR)
    if executor not in EXECUTORS:
        raise ConfigError(f"--executor must be one of {', '.join(EXECUTORS)}, got '{executor}'")
    workers = pick("workers", None)
    if workers is not None and int(workers) < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    threads = pick("threads", None)
    if threads is not None and int(threads) < 1:
        raise ConfigError(f"--threads must be >= 1, got {threads}")
    cfg["threads"] = None if threads is None else int(threads)
    retries = int(pick("retries", DEFAULT_RETRIES))
    if retries < 0:
        raise ConfigError(f"--retries must be >= 0, got {retries}")
    address = given.get("address")
    if address is not None and executor != "ray":
        raise ConfigError("--address only applies to --executor ray")
    gpus_per_job = float(pick("gpus_per_job", 1.0))
    cpus_per_job = float(pick("cpus_per_job", 1.0))
    if gpus_per_job < 0 or cpus_per_job <= 0:
        raise ConfigError("--gpus-per-job must be >= 0 and --cpus-per-job > 0")
    if executor == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ConfigError("--executor ray needs the optional package ray: pip install 'ray>=2.9' "
                              "(or pip install '.[ray]')") from None
    cfg.update(executor=executor, workers=None if workers is None else int(workers), retries=retries,
               address=address, gpus_per_job=gpus_per_job, cpus_per_job=cpus_per_job)

    # dataset (validated by building it and listing its shapes: no mesh is read)
    dataset = pick("dataset", DEFAULT_DATASET)
    options: dict[str, Any] = {}
    data_dir = pick("data_dir", None)
    if data_dir is not None:
        options["data_dir"] = _existing_path("--data-dir", data_dir, "directory")
    list_file = pick("list", None)
    if list_file is not None:
        options["list_file"] = _existing_path("--list", list_file, "file")
    limit = pick("limit", None)
    if limit is not None and int(limit) < 1:
        raise ConfigError(f"--limit must be >= 1, got {limit}")
    try:
        ds = load_dataset(dataset, options)
        names = list(ds.names())[: None if limit is None else int(limit)]
    except (ValueError, FileNotFoundError, OSError) as exc:  # DatasetError is a ValueError
        raise ConfigError(str(exc).splitlines()[0] if str(exc) else one_line(exc)) from None
    except ImportError as exc:
        raise ConfigError(f"datasets could not be imported ({one_line(exc)})") from None
    if not names:
        raise ConfigError(f"dataset '{dataset}' has no shapes with these options ({options or 'none'})")
    cfg.update(dataset=dataset, dataset_options=options, data_dir=options.get("data_dir"), shapes=names)

    # caches and output
    cfg["cache_dir"] = None if given.get("no_cache") else str(cache_root(pick("cache_dir", None)))
    if out_dir is None:
        out_dir = Path("runs") / _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(out_dir).expanduser()
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out_dir}: exists and is not a directory")
    cfg["out"] = str(out)
    cfg["quiet"] = bool(pick("quiet", False))
    cfg["options"] = {k: v for k, v in vars(args).items() if k not in ("command", "resume")}
    cfg["options"].update({"out": str(out)})
    previous = out / "config.json"
    if previous.is_file() and saved is None:
        saved_cfg = json.loads(previous.read_text())
        changed = [k for k in PROTOCOL_KEYS if k in saved_cfg and saved_cfg.get(k) != cfg.get(k)]
        if changed:
            k = changed[0]
            raise ConfigError(f"--out {out_dir} holds a run with a different {k} ({saved_cfg.get(k)!r} there, "
                              f"{cfg.get(k)!r} now); use another --out")
    return cfg


def import_plugins_safe(plugins: Iterable[str]) -> None:
    for name in plugins:
        try:
            import_plugins([name])
        except (ImportError, AttributeError) as exc:
            raise ConfigError(f"--plugin {name}: cannot load ({one_line(exc)})") from None


def default_methods(known: list[str]) -> list[str]:
    """All registered methods, the four SPEC methods first in table order."""
    order = ["bof", "sdf", "udf", "sals"]
    return [m for m in order if m in known] + [m for m in known if m not in order]


def latest_run_dir(root: Path = Path("runs")) -> Path | None:
    if not root.is_dir():
        return None
    runs = sorted(p for p in root.iterdir() if (p / "config.json").is_file())
    return runs[-1] if runs else None


def build_tasks(cfg: dict) -> tuple[list[FloorSpec], list[JobSpec]]:
    """Floor tasks (one per shape, first seed) and jobs (shapes x methods x seeds, in table order)."""
    plugins = tuple(cfg.get("plugins", []))
    floors = [
        FloorSpec(dataset=cfg["dataset"], dataset_options=cfg["dataset_options"], shape=s,
                  eval_points=cfg["eval_points"], metric_preset=cfg["metric_preset"], seed=cfg["seeds"][0],
                  plugins=plugins, threads=cfg.get("threads"))
        for s in cfg["shapes"]
    ]
    jobs = [
        JobSpec(dataset=cfg["dataset"], dataset_options=cfg["dataset_options"], shape=s, method=m,
                params=cfg["method_params"].get(m, {}), mode=cfg["mode"], budget=cfg["budget"], grid=cfg["grid"],
                eval_points=cfg["eval_points"], metric_preset=cfg["metric_preset"], seed=seed,
                cache_dir=cfg["cache_dir"], plugins=plugins, threads=cfg.get("threads"))
        for s in cfg["shapes"] for m in cfg["methods"] for seed in cfg["seeds"]
    ]
    return floors, jobs


def environment_record(executor: str | None = None) -> dict:
    """Git commit, package versions, device, CPU model, GPU name, host: for config.json."""
    rec: dict[str, Any] = {"versions": package_versions(), "python": sys.version.split()[0],
                           "platform": platform.platform(), "host": socket.gethostname(), "cpu_count": os.cpu_count()}
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, timeout=10)
        rec["git_commit"] = commit.stdout.strip() or None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO,
                               capture_output=True, text=True, timeout=10)
        rec["git_dirty"] = bool(dirty.stdout.strip()) if dirty.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        rec["git_commit"] = None
    rec["cpu_model"] = cpu_model()
    try:
        import torch
        from methods.device import describe_device, get_device

        rec["device"] = describe_device(get_device())
        rec["torch_threads"] = torch.get_num_threads()
        rec["gpu"] = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
        rec["cuda"] = torch.version.cuda
    except Exception as exc:  # noqa: BLE001
        rec["device"] = f"unknown ({one_line(exc)})"
    return rec


def cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


# =============================================================================================
# The driver
# =============================================================================================


def safe_name(name: str) -> str:
    return str(name).replace(os.sep, "_").replace("/", "_") or "_"


def mesh_relpath(shape: str, method: str, seed: int, first_seed: int) -> str:
    stem = method if seed == first_seed else f"{method}_seed{seed}"
    return f"meshes/{safe_name(shape)}/{stem}.ply"


class _Display:
    """One tqdm bar over tasks with the current stage in the postfix; quiet: one line per task."""

    def __init__(self, total: int, quiet: bool, done: int = 0):
        self.quiet = quiet
        self.total = total
        self.count = done
        self.bar = None
        self._last = 0.0
        if not quiet:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, unit="task", dynamic_ncols=True, file=sys.stderr,
                            desc="salsbench")

    def stage(self, label: str, stage: str, **info) -> None:
        if self.bar is None:
            return
        now = time.monotonic()
        if now - self._last < 0.3 and stage == "fitting":
            return
        self._last = now
        text = f"{label} {stage}"
        if info.get("loss") is not None:
            text += f" loss={float(info['loss']):.4g}"
        if info.get("step") is not None:
            text += f" step={info['step']}"
        self.bar.set_postfix_str(text, refresh=True)

    def finished(self, result: JobResult) -> None:
        self.count += 1
        if self.bar is not None:
            self.bar.update(1)
            if not result.ok:
                self.bar.write(f"FAILED {result.spec.label}: {result.error}", file=sys.stderr)
            return
        line = f"[{self.count}/{self.total}] {result.status:6s} {result.spec.label}"
        m = result.metrics
        if result.ok and m:
            parts = [f"{k}={m[k]:.4g}" for k in ("cd", "f1_005", "ecd", "ef1") if isinstance(m.get(k), (int, float))]
            line += " " + " ".join(parts)
        line += f" {result.timings.get('total_s', 0.0):.1f}s"
        if result.cache:
            line += f" (cache: {','.join(result.cache)})"
        if not result.ok:
            line += f" -- {result.error}"
        print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def record_result(db, run_dir: Path, result: JobResult, first_seed: int) -> None:
    """Write the mesh bytes (if any) and commit the row: the driver's only writing path."""
    spec = result.spec
    mesh_path = None
    if result.mesh_ply is not None:
        mesh_path = (f"meshes/{safe_name(spec.shape)}/gt.ply" if result.kind == "floor"
                     else mesh_relpath(spec.shape, spec.method, spec.seed, first_seed))
        _atomic_write(run_dir / mesh_path, result.mesh_ply)
    if result.kind == "floor":
        db.write_floor({
            "floor_hash": result.key, "shape": spec.shape, "shape_hash": result.shape_hash,
            "shape_kind": result.shape_kind, "source": result.shape_info.get("source"),
            "gt_vertices": result.shape_info.get("gt_vertices"), "gt_faces": result.shape_info.get("gt_faces"),
            "status": result.status, "error": result.error, "seed": spec.seed, "eval_points": spec.eval_points,
            "metric_preset": spec.metric_preset, "mesh_path": mesh_path, "finished": result.finished,
        }, result.metrics, result.timings)
        return
    db.write_job({
        "config_hash": result.key, "shape": spec.shape, "method": spec.method, "mode": spec.mode, "seed": spec.seed,
        "status": result.status, "error": result.error, "traceback": result.traceback, "params": spec.params,
        "budget": spec.budget if spec.mode == "neural" else None, "grid": spec.grid, "eval_points": spec.eval_points,
        "metric_preset": spec.metric_preset, "shape_hash": result.shape_hash, "shape_kind": result.shape_kind,
        "fit_loss": result.fit_loss, "attempts": result.attempts, "cache": ",".join(result.cache) or None,
        "mesh_path": mesh_path, "device": result.device, "host": result.host, "versions": result.versions,
        "info": result.info, "started": result.started, "finished": result.finished,
    }, result.metrics, result.timings)


def failed_from_exception(spec, exc: BaseException, attempts: int = 1) -> JobResult:
    """A failed result for a task whose worker died or whose result never came back."""
    return JobResult(kind=spec.kind, key=spec.key, spec=spec, status="failed", error=one_line(exc, "worker"),
                     traceback="".join(_traceback.format_exception(exc)), started=None, finished=now_iso(),
                     attempts=attempts)


def run(cfg: dict, executor=None) -> Path:
    """Run every job of ``cfg`` not yet finished in its run directory; return the run directory.

    Writes config.json first, commits each result as it arrives, then results.csv and the reports.
    """
    from benchmark.executors import make_executor
    from benchmark.records import ResultsDB

    run_dir = Path(cfg["out"])
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg = dict(cfg)
    cfg["environment"] = environment_record(cfg.get("executor"))
    for key in ("device", "cpu_model", "gpu", "git_commit"):  # top level too: the reports read these
        cfg[key] = cfg["environment"].get(key)
    cfg["started"] = now_iso()
    cfg["command"] = " ".join([Path(sys.argv[0]).name] + sys.argv[1:]) if sys.argv else ""
    _atomic_write(run_dir / "config.json", json.dumps(cfg, indent=2, sort_keys=True, default=str).encode())

    floors, jobs = build_tasks(cfg)
    db = ResultsDB(run_dir / "results.db")
    db.set_meta("config", json.dumps(cfg, sort_keys=True, default=str))
    done_jobs, done_floors = db.ok_hashes("jobs"), db.ok_hashes("floor")
    attempts = db.attempts()
    todo = [f for f in floors if f.key not in done_floors] + [j for j in jobs if j.key not in done_jobs]
    # table order with each shape's floor first, so the local executor finishes shape by shape
    order = {s: i for i, s in enumerate(cfg["shapes"])}
    todo.sort(key=lambda t: (order[t.shape], 0 if t.kind == "floor" else 1))
    total = len(floors) + len(jobs)
    skipped = total - len(todo)
    print(f"salsbench: {len(jobs)} jobs + {len(floors)} floor tasks, {skipped} already done, "
          f"run dir {run_dir}", file=sys.stderr, flush=True)
    display = _Display(total, cfg.get("quiet", False), done=skipped)
    first_seed = cfg["seeds"][0]
    if executor is None:
        executor = make_executor(cfg)
    t0 = time.perf_counter()
    try:
        for spec, outcome in executor.run(run_task, todo, on_stage=display.stage):
            if isinstance(outcome, BaseException):
                outcome = failed_from_exception(spec, outcome)
            if outcome.kind == "job":
                outcome.attempts = attempts.get(outcome.key, 0) + max(1, outcome.attempts)
            record_result(db, run_dir, outcome, first_seed)
            display.finished(outcome)
    finally:
        display.close()
        executor.close()
    wall = time.perf_counter() - t0
    export(run_dir, db=db, cfg=cfg)
    db.close()
    print(f"salsbench: done in {wall:.1f} s; results in {run_dir}", file=sys.stderr, flush=True)
    return run_dir


# =============================================================================================
# Export: results.csv and reports
# =============================================================================================


def results_frame(db, cfg: dict | None = None):
    """The jobs table as the results.csv frame: contract columns first, rows in table order."""
    import pandas as pd

    df = db.frame("jobs")
    if df.empty:
        df = pd.DataFrame(columns=list(RESULT_COLUMNS))
    for col in RESULT_COLUMNS:
        if col not in df.columns:
            df[col] = np.nan
    drop = {"traceback", "versions", "info", "extra"}
    rest = [c for c in df.columns if c not in RESULT_COLUMNS and c not in drop]
    df = df[list(RESULT_COLUMNS) + rest]
    if cfg:
        shape_rank = {s: i for i, s in enumerate(cfg.get("shapes", []))}
        method_rank = {m: i for i, m in enumerate(cfg.get("methods", []))}
        df = df.assign(_s=df["shape"].map(shape_rank).fillna(len(shape_rank)),
                       _m=df["method"].map(method_rank).fillna(len(method_rank)))
        df = df.sort_values(["_s", "shape", "_m", "method", "seed"], kind="stable").drop(columns=["_s", "_m"])
    else:
        df = df.sort_values(["shape", "method", "seed"], kind="stable")
    return df.reset_index(drop=True)


def floor_frame(db, cfg: dict | None = None):
    df = db.frame("floor")
    if cfg and not df.empty:
        rank = {s: i for i, s in enumerate(cfg.get("shapes", []))}
        df = df.assign(_s=df["shape"].map(rank).fillna(len(rank))).sort_values(["_s", "shape"]).drop(columns="_s")
    return df.reset_index(drop=True)


def export(run_dir: Path, db=None, cfg: dict | None = None, out_dir: Path | None = None) -> dict[str, Any]:
    """Write results.csv (and floor.csv) and call ``reports.write_reports``; return what was written."""
    from benchmark.records import open_run_db

    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    own = db is None
    if own:
        db = open_run_db(run_dir, must_exist=True)
    if cfg is None:
        cfg = json.loads((run_dir / "config.json").read_text()) if (run_dir / "config.json").is_file() else {}
    results = results_frame(db, cfg)
    floor = floor_frame(db, cfg)
    if own:
        db.close()
    results.to_csv(out_dir / "results.csv", index=False, float_format="%.9g")
    floor.to_csv(out_dir / "floor.csv", index=False, float_format="%.9g")
    written = {"results": out_dir / "results.csv", "floor": out_dir / "floor.csv"}
    written["reports"] = write_reports_guarded(results, floor, cfg, out_dir, run_dir / "meshes")
    return written


def write_reports_guarded(results, floor, cfg, out_dir: Path, meshes_dir: Path):
    """``reports.write_reports`` when the reports module provides it; a failure there is reported on
    stderr and never loses results.csv."""
    try:
        import reports
    except ImportError as exc:
        print(f"salsbench: reports not written (cannot import reports: {one_line(exc)})", file=sys.stderr)
        return None
    writer = getattr(reports, "write_reports", None)
    if writer is None:
        print("salsbench: reports not written (reports.write_reports is not available yet)", file=sys.stderr)
        return None
    try:
        return writer(results, floor, cfg, Path(out_dir), Path(meshes_dir))
    except Exception as exc:  # noqa: BLE001 -- the results are safe in results.db / results.csv
        print(f"salsbench: writing reports failed: {one_line(exc)}", file=sys.stderr)
        return None


# =============================================================================================
# Command line
# =============================================================================================


class _OneLineParser(argparse.ArgumentParser):
    """argparse whose errors are one line on stderr (exit status 2)."""

    def error(self, message: str):  # noqa: D401
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(
        prog="run_benchmark.py",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Benchmark neural implicit surface representations (BOF, SDF, UDF, SALS) on CAD meshes.\n"
            "Jobs = shapes x methods x seeds. Results go to OUT/results.db (SQLite, one row per job,\n"
            "committed as each job ends), OUT/results.csv, OUT/summary.md|tex, OUT/timing.csv|md,\n"
            "OUT/report.html and OUT/meshes/<shape>/{gt,<method>}.ply (canonical frame [-1,1]^3).\n"
            "Re-running into the same --out (or --resume) skips finished jobs and retries failed ones.\n\n"
            "Regenerate tables/report from finished runs (several side by side):\n"
            "  run_benchmark.py report RUN_DIR [RUN_DIR ...] [--out DIR]"
        ),
        epilog="Caches (exact fields, fitted weights, extracted meshes) live in $SALSBENCH_CACHE or "
               "~/.cache/salsbench. SALSBENCH_DEVICE=cpu|cuda forces the torch device.",
    )
    a = p.add_argument
    a("--methods", nargs="+", metavar="METHOD", help="methods to run (default: all registered: bof sdf udf sals)")
    a("--dataset", metavar="NAME", help="dataset: builtin (default; 4 generated CAD-like shapes, no download), "
                                        "abc, abc-nonmanifold, meshes (any folder of mesh files)")
    a("--data-dir", dest="data_dir", metavar="DIR", help="folder of mesh files (abc, abc-nonmanifold, meshes)")
    a("--list", metavar="FILE", help="text file of shape names, one per line (e.g. the SALS ABC test lists)")
    a("--limit", type=int, metavar="N", help="use only the first N shapes of the dataset")
    a("--mode", choices=MODES, help="neural (default): fit a network per shape and method, extract from it; "
                                    "oracle: extract from the exact field (no fitting; isolates extraction error)")
    a("--budget", metavar="NAME", help="fitting budget, the same for every method: tiny, quick (default; sized so "
                                       "the default run ends in ~10 min on 2 CPU cores), paper (100k steps)")
    a("--grid", type=int, metavar="N", help=f"grid points per axis on [-1,1] (default {DEFAULT_GRID}; >= {MIN_GRID}); "
                                            "spacing 2/(N-1) canonical units")
    a("--eval-points", dest="eval_points", type=int, metavar="N",
      help="surface samples per mesh for the metrics (default: the preset's n, 1,000,000 for 'default', "
           "100,000 for 'ndc'); stated in every table caption")
    a("--metric-preset", dest="metric_preset", metavar="NAME",
      help="metric protocol: default (canonical frame, Chamfer-L1, F1@0.005/0.01, ECD/EF1) or ndc (NDC's script)")
    a("--seed", nargs="+", type=int, metavar="S", help="seeds (default 0); each seed is a separate job per shape "
                                                       "and method (sampling, network init, metric samples)")
    a("--out", metavar="DIR", help="run directory (default runs/<YYYYmmdd-HHMMSS>); an existing one is resumed")
    a("--resume", action="store_true", default=None,
      help="continue a run: skip finished jobs, retry failed ones; options not given are read from "
           "OUT/config.json (without --out: the latest run under runs/)")
    a("--executor", choices=EXECUTORS, help="local (default; in-process, sequential), process (--workers local "
                                            "processes), ray (Ray tasks, local instance or --address cluster)")
    a("--workers", type=int, metavar="K", help="parallel jobs for process (default: CPU cores) and for a local ray "
                                               "instance (its CPU count); torch threads per job = max(1, cores // K)")
    a("--address", metavar="ADDR", help="ray cluster to join: 'auto' (a cluster started with `ray start`) or "
                                        "host:port; without it a local ray instance is started")
    a("--gpus-per-job", dest="gpus_per_job", type=float, metavar="F",
      help="ray: GPUs a fitting job asks for when the cluster has GPUs (default 1; fractions allowed, e.g. 0.5)")
    a("--cpus-per-job", dest="cpus_per_job", type=float, metavar="C", help="ray: CPUs per job (default 1)")
    a("--threads", type=int, metavar="T",
      help="torch CPU threads per job (default: torch's own, i.e. all cores, for local; cores // workers for "
           "process; --cpus-per-job for ray). On a loaded machine 1 thread can be far faster than 2")
    a("--retries", type=int, metavar="R", help=f"times a job whose worker died is retried (default {DEFAULT_RETRIES}); "
                                               "jobs that raise are recorded failed at once")
    a("--method-param", dest="method_param", action="append", metavar="METHOD.NAME=VALUE",
      help="override an extractor parameter, e.g. sals.o_threshold=0.2 (repeatable)")
    a("--cache-dir", dest="cache_dir", metavar="DIR", help="cache root (default $SALSBENCH_CACHE or ~/.cache/salsbench)")
    a("--no-cache", dest="no_cache", action="store_true", default=None,
      help="do not read or write the weights/mesh/field caches")
    a("--plugin", action="append", metavar="MODULE",
      help="import MODULE (or MODULE:FUNCTION, then call it) first, in the driver and every worker, "
           "to register extra methods or datasets (repeatable)")
    a("--quiet", action="store_true", default=None, help="no progress bar; one line per finished job (CI logs)")
    return p


def build_report_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(prog="run_benchmark.py report",
                       description="Regenerate results.csv, tables and report.html from run directories' "
                                   "results.db; with several runs, put them side by side.")
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run directories (each holds results.db)")
    p.add_argument("--out", metavar="DIR", help="where to write (default: the run directory itself; for several "
                                                "runs: runs/compare-<timestamp>)")
    return p


def report_main(argv: Sequence[str]) -> int:
    args = build_report_parser().parse_args(list(argv))
    for r in args.runs:
        if not (Path(r) / "results.db").is_file():
            print(f"run_benchmark.py report: error: {r}: no results.db (not a salsbench run directory)", file=sys.stderr)
            return 2
    if len(args.runs) == 1:
        written = export(Path(args.runs[0]), out_dir=Path(args.out) if args.out else None)
        print(f"wrote {written['results']}", file=sys.stderr)
        return 0
    import reports
    from benchmark.records import open_run_db

    out = Path(args.out) if args.out else Path("runs") / _dt.datetime.now().strftime("compare-%Y%m%d-%H%M%S")
    runs = []
    for r in args.runs:
        run_dir = Path(r)
        cfg = json.loads((run_dir / "config.json").read_text()) if (run_dir / "config.json").is_file() else {}
        with open_run_db(run_dir, must_exist=True) as db:
            runs.append({"name": run_dir.name, "run_dir": run_dir, "results": results_frame(db, cfg),
                         "floor": floor_frame(db, cfg), "config": cfg, "meshes_dir": run_dir / "meshes"})
    compare = getattr(reports, "compare_runs", None)
    if compare is None:
        print("run_benchmark.py report: error: reports.compare_runs is not available", file=sys.stderr)
        return 1
    out.mkdir(parents=True, exist_ok=True)
    compare(runs, out)
    print(f"wrote comparison of {len(runs)} runs to {out}", file=sys.stderr)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "report":
        return report_main(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        cfg = resolve_config(args)
    except ConfigError as exc:
        print(f"run_benchmark.py: error: {exc}", file=sys.stderr)
        return 2
    run(cfg)
    return 0
