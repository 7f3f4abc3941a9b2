"""``run_benchmark.py export-inputs``: write the inputs a run gives its methods, as files, so that a
method outside this repository can be run on exactly the same inputs.

One folder per (input, seed) under ``--out``, the shapes named as the dataset names them:

* ``--task reconstruct``: per corruption and seed, ``<out>/<corruption>-s<seed>/``, laid out as the
  ``pointclouds`` dataset reads it: ``<shape>.<ply|npz>`` (the very cloud of
  :func:`foundation.corruptions.input_point_cloud` on the job's sampler stream, with each point's sensor
  position for a scan) and ``<shape>.gt.off`` (the GT mesh), both in the shape's source frame (the
  mesh file's own units and position), so ``run_benchmark.py --task reconstruct --dataset
  pointclouds --data-dir <folder>`` reads them back.
* ``--task encode``: per seed, ``<out>/encode-s<seed>/``: ``<shape>.gt.off``, the GT in the
  canonical frame every method fits in, and ``<shape>.samples.npz``, the shared sampler's draw of
  the run's encode budget (``centres``, ``points``, ``segments``, ``group``: float32, canonical
  frame, :mod:`foundation.sampler`); the labels are the exact fields of the GT at those samples
  (docs/PROTOCOL.md).

Meshes are written as OFF with 17 significant digits (read back exactly; a PLY written by trimesh
holds float32).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["export_inputs", "export_clouds", "export_samples", "write_off"]

#: Cloud file formats the export writes.
FORMATS = ("ply", "npz")


def export_inputs(plan, out: str | Path, fmt: str = "ply", progress=None) -> list[Path]:
    """The inputs of ``plan``'s task under ``out`` (module docstring); returns the folders."""
    if plan.config.task == "reconstruct":
        return export_clouds(plan, out, fmt, progress)
    return export_samples(plan, out, progress)


def _shapes(plan, progress):
    """(name, shape) of every shape of the plan that loads; a failing one is reported and skipped."""
    from datasets import MeshError
    from tasks.load import load_dataset

    dataset = load_dataset(plan.config.dataset, plan.dataset_options)
    for name in plan.shapes:
        try:
            yield name, dataset.load(name)
        except MeshError as exc:
            if progress is not None:
                progress(f"{name}: skipped ({exc})")


def export_samples(plan, out: str | Path, progress=None) -> list[Path]:
    """Write the canonical GT and the shared sampler's draw of every (seed, shape) of an encode
    ``plan`` under ``out``; returns the folders."""
    import io

    import numpy as np

    from foundation.sampler import sample_training_data
    from foundation.seeding import job_streams
    from foundation.storage import atomic_write

    budget = plan.budgets.get("encode")
    folders = {seed: Path(out) / f"encode-s{seed}" for seed in plan.config.seeds}
    for folder in folders.values():
        folder.mkdir(parents=True, exist_ok=True)
    for name, shape in _shapes(plan, progress):
        for seed, folder in folders.items():
            write_off(folder / f"{name}.gt.off", shape.vertices, shape.faces)
            if budget is None:  # oracle mode: no samples are drawn
                continue
            samples = sample_training_data(shape.vertices, shape.faces, budget.num_samples,
                                           job_streams(shape.content_hash, seed).sampler_rng())
            buffer = io.BytesIO()
            np.savez(buffer, centres=samples.centres, points=samples.points, segments=samples.segments,
                     group=samples.group)
            atomic_write(folder / f"{name}.samples.npz", buffer.getvalue())
            if progress is not None:
                progress(f"{folder / name}: GT and {len(samples):,} samples")
    return list(folders.values())


def export_clouds(plan, out: str | Path, fmt: str = "ply", progress=None) -> list[Path]:
    """Write every (corruption, seed, shape) input cloud of ``plan`` (a reconstruct plan on a mesh
    dataset; its swept ``pc_corruption`` values, or its one) under ``out``; returns the folders.
    A shape that cannot be loaded is skipped with its one-line error passed to ``progress``."""
    from datasets.pointclouds import write_point_cloud
    from foundation.corruptions import input_point_cloud

    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    config = plan.config
    corruptions = list(config.sweep.get("pc_corruption", ())) or [config.pc_corruption]
    folders = {(c, s): Path(out) / f"{c}-s{s}" for c in corruptions for s in config.seeds}
    for folder in folders.values():
        folder.mkdir(parents=True, exist_ok=True)
    for name, shape in _shapes(plan, progress):
        for (corruption, seed), folder in folders.items():
            points, sensors = input_point_cloud(shape, config.pc_points, config.pc_noise, seed, corruption)
            invert = shape.transform.invert
            write_point_cloud(folder / f"{name}.{fmt}", invert(points), None if sensors is None else invert(sensors))
            write_off(folder / f"{name}.gt.off", invert(shape.vertices), shape.faces)
            if progress is not None:
                progress(f"{folder / name}.{fmt}: {len(points):,} points")
    return list(folders.values())


def write_off(path: Path, vertices, faces) -> None:
    """An OFF file of a triangle mesh whose float64 coordinates read back exactly (``%.17g``),
    written atomically."""
    import io

    import numpy as np

    from foundation.storage import atomic_write

    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    text = io.StringIO()
    text.write(f"OFF\n{len(vertices)} {len(faces)} 0\n")
    np.savetxt(text, vertices, fmt="%.17g")
    np.savetxt(text, np.hstack([np.full((len(faces), 1), 3), faces]), fmt="%d")
    atomic_write(path, text.getvalue().encode("ascii"))
