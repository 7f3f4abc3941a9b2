"""The score task: meshes made elsewhere, read, moved into the canonical frame and scored against
the GT like any method's (``run_benchmark.py score --pred-dir DIR --name NAME``). Its rows are not
methods: each is a folder of predictions under the name the user gives it
(:func:`tasks.rows.predictions_row`), with the parameters :data:`PARAMETERS`, beside the same floor
rows and tables as any run, so ``run_benchmark.py report runs/A runs/B`` sets it beside the built-in
methods on the same shapes.

Matching rule (:func:`prediction_file`): the prediction of shape ``S`` is ``<pred_dir>/S.<ext>``,
else ``<pred_dir>/S/NAME.<ext>``, for ``<ext>`` a mesh extension of
:data:`datasets.io.MESH_EXTENSIONS`; two candidates for one shape are refused as ambiguous. A shape
without a prediction is a failed job naming what was looked for; files that match no shape are
listed (:func:`unmatched_predictions`) and ignored.

Frames: ``original`` (default) -- the prediction is in the GT mesh file's own frame, and the
shape's canonical transform moves it; ``canonical`` -- it is already in the canonical frame of
:mod:`datasets.io` (bounding box centred, largest side 1.99).

Seconds: an optional ``seconds.csv`` in ``pred_dir`` (columns ``shape``, ``seconds``) gives each
prediction's time; it is recorded as the job's ``external_s``.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from foundation.params import Param
from foundation.timing import stage
from tasks.context import TaskContext, score

#: Frames a prediction may be given in.
FRAMES = ("original", "canonical")
#: The parameters of a row of the score task.
PARAMETERS = {
    "pred_dir": Param("", "folder of the predicted meshes (<shape>.<ext> or <shape>/<name>.<ext>)"),
    "pred_frame": Param("original", "the frame of the predictions: original (the GT file's) or canonical",
                        choices=FRAMES),
}
#: The optional per-shape seconds beside the predictions.
SECONDS_FILE = "seconds.csv"


def run(ctx: TaskContext) -> None:
    from datasets.io import read_mesh_file

    spec = ctx.spec
    pred_dir, frame = spec.params["pred_dir"], spec.params["pred_frame"]
    with stage("read"):
        path = prediction_file(pred_dir, spec.shape, spec.method)
        vertices, faces = read_mesh_file(path)
    if frame == "original":
        vertices = ctx.shape.transform.apply(vertices)
    ctx.result.info["prediction"] = str(path)
    seconds = external_seconds(pred_dir).get(spec.shape)
    if seconds is not None:
        ctx.timer.add("external_s", seconds)
    score(ctx, vertices, faces)


def check_predictions(params: dict) -> None:
    """ValueError (one line) unless ``params['pred_dir']`` is a folder."""
    if not params["pred_dir"] or not Path(params["pred_dir"]).is_dir():
        raise ValueError(f"pred_dir {params['pred_dir'] or '(not given)'}: not a folder of predicted meshes "
                         f"(run_benchmark.py score --pred-dir DIR --name NAME)")


def prediction_file(pred_dir: str | Path, shape: str, name: str) -> Path:
    """The prediction of ``shape`` (module docstring's rule); FileNotFoundError (one line) when
    there is none, ValueError when there are several."""
    from datasets.io import MESH_EXTENSIONS

    pred_dir = Path(pred_dir)
    found = [p for ext in MESH_EXTENSIONS for p in (pred_dir / f"{shape}{ext}", pred_dir / shape / f"{name}{ext}")
             if p.is_file()]
    if not found:
        raise FileNotFoundError(f"no prediction for shape '{shape}' in {pred_dir} (looked for {shape}.<ext> and "
                                f"{shape}/{name}.<ext>, <ext> one of {' '.join(MESH_EXTENSIONS)})")
    if len(found) > 1:
        raise ValueError(f"several predictions for shape '{shape}': {', '.join(str(p) for p in found)}; keep one")
    return found[0]


def unmatched_predictions(pred_dir: str | Path, shapes, name: str) -> list[str]:
    """Mesh files of ``pred_dir`` (top level, and ``<dir>/NAME.<ext>``) that match none of ``shapes``."""
    from datasets.io import MESH_EXTENSIONS

    pred_dir, shapes = Path(pred_dir), set(shapes)
    files = [p for p in pred_dir.iterdir() if p.is_file() and p.suffix.lower() in MESH_EXTENSIONS]
    nested = [p for p in pred_dir.glob(f"*/{name}.*") if p.suffix.lower() in MESH_EXTENSIONS]
    return sorted([p.name for p in files if p.stem not in shapes]
                  + [f"{p.parent.name}/{p.name}" for p in nested if p.parent.name not in shapes])


def external_seconds(pred_dir: str | Path) -> dict[str, float]:
    """{shape: seconds} of ``pred_dir/seconds.csv`` ({} without one); ValueError naming the line
    of a malformed row."""
    path = Path(pred_dir) / SECONDS_FILE
    if not path.is_file():
        return {}
    seconds = {}
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        if not reader.fieldnames or not {"shape", "seconds"} <= set(reader.fieldnames):
            raise ValueError(f"{path}: needs the columns shape and seconds, got {reader.fieldnames}")
        for line, row in enumerate(reader, start=2):
            try:
                value = float(row["seconds"])
            except (TypeError, ValueError):
                value = math.nan
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{path}, line {line}: seconds {row['seconds']!r} is not a number >= 0")
            seconds[row["shape"]] = value
    return seconds
