"""Loading a task's shape: the dataset's mesh or cloud in the canonical frame, refused in one line
when it is over the run's size limits (``--max-faces``, ``--max-points``), before or after it is read."""

from __future__ import annotations

import json
from functools import lru_cache


class ShapeTooLarge(ValueError):
    """A shape over the run's size limits (``--max-faces``, ``--max-points``); one line naming its file."""


@lru_cache(maxsize=8)
def _dataset_cached(name: str, options_json: str):
    from datasets import get_dataset

    return get_dataset(name, **json.loads(options_json))


def load_dataset(name: str, options: dict):
    """The dataset ``name`` built with ``options`` (cached per process)."""
    return _dataset_cached(name, json.dumps(options, sort_keys=True))


def load_shape(spec):
    """The shape of a task spec (its dataset, options and shape name), checked against the spec's
    ``max_faces`` and ``max_points`` (:func:`check_stored_size` on its files, :func:`check_size`
    on what was read)."""
    dataset = load_dataset(spec.dataset, spec.dataset_options)
    check_stored_size(dataset.stored_files(spec.shape), spec.max_faces, spec.max_points)
    shape = dataset.load(spec.shape)
    check_size(shape, spec.max_faces, spec.max_points)
    return shape


def check_stored_size(files, max_faces: int | None, max_points: int | None) -> None:
    """Raise :class:`ShapeTooLarge` when one of ``files`` ((path, 'mesh' or 'cloud') pairs:
    ``Dataset.stored_files``) stores more faces (a mesh) or points (a cloud) than the limits, as its
    header or a bounded-memory count says (:func:`datasets.stored_size.stored_count`), before it
    is read. None: no limit."""
    from datasets.stored_size import stored_count

    for path, holds in files:
        what, limit, flag = ("faces", max_faces, "--max-faces") if holds == "mesh" else ("points", max_points,
                                                                                           "--max-points")
        count = stored_count(path, what) if limit is not None else None
        if count is not None and count > limit:
            raise ShapeTooLarge(f"{path}: stores {count:,} {what}, over the limit of {limit:,} ({flag}); not read")


def check_size(shape, max_faces: int | None, max_points: int | None) -> None:
    """Raise :class:`ShapeTooLarge` when ``shape`` has more faces than ``max_faces`` or more input
    points than ``max_points`` (None: no limit)."""
    where = shape.source or shape.name
    if max_faces is not None and len(shape.faces) > max_faces:
        raise ShapeTooLarge(f"{where}: {len(shape.faces):,} faces, over the limit of {max_faces:,} (--max-faces)")
    if max_points is not None and shape.points is not None and len(shape.points) > max_points:
        raise ShapeTooLarge(f"{where}: {len(shape.points):,} points, over the limit of {max_points:,} (--max-points)")
