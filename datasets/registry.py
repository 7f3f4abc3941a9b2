"""The dataset registry and the :class:`Dataset` protocol.

A dataset is a named, ordered collection of shapes that loads lazily:

* ``names()`` lists the shape names (it may scan a directory or read a list file, never a mesh);
* ``load(name)`` reads/generates one shape as a canonical-frame :class:`~datasets.io.Shape`, and
  raises :class:`~datasets.io.MeshError` (one line naming the file) when that shape is unusable;
* ``for shape in dataset`` loads the shapes one after the other (a failure stops the loop: to go on
  past a bad shape iterate ``names()`` and catch per shape, or use :meth:`Dataset.iter_safe`);
* ``stored_files(name)`` names the files ``load(name)`` reads (for a size check before reading);
* ``describe()`` is the JSON-ready record of the dataset and its options for a run's config.json.

Datasets declare themselves with :func:`register_dataset` and are built with :func:`get_dataset`.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from foundation.registry import Registry
from datasets.io import MeshError, Shape

#: The dataset a run uses when none is named.
DEFAULT_DATASET = "builtin"

#: The environment variable that moves the shared data folder (tests/conftest.py reads it too).
SHARED_DATA_ENV = "SALSBENCH_SHARED_DATA"


def shared_data_dir() -> Path:
    """The shared data folder: ``$SALSBENCH_SHARED_DATA`` when set, else ``../shared/data`` beside
    the checkout. Read at each call (not cached), so the variable may change during a session."""
    return Path(os.environ.get(SHARED_DATA_ENV) or Path(__file__).resolve().parents[2] / "shared" / "data")


class DatasetError(ValueError):
    """A dataset that cannot be built as asked (bad option, unknown shape, ...); one-line message."""


class DatasetNotFoundError(DatasetError, FileNotFoundError):
    """A data directory or list file that does not exist; one-line message naming the path."""


class MissingShapesWarning(UserWarning):
    """Some entries of a list file have no mesh file (the dataset goes on without them)."""


class Dataset:
    """Base class of a dataset. Subclasses set ``name`` and implement :meth:`names`, :meth:`load`
    and :meth:`options`."""

    #: The registry name (e.g. 'abc').
    name: str = ""
    #: Whether the shapes are point clouds (only the reconstruct task can use them).
    point_clouds: bool = False
    #: The axis of the canonical frame that points up in the scene ('x', 'y' or 'z'); '' when the
    #: shapes have no stated up (CAD parts). Renderers keep it vertical in the image.
    up_axis: str = ""

    def names(self) -> list[str]:
        """Shape names in dataset order; never opens a mesh file."""
        raise NotImplementedError

    def load(self, name: str) -> Shape:
        """One shape in the canonical frame; raises MeshError when it is unusable."""
        raise NotImplementedError

    def options(self) -> dict[str, Any]:
        """The options this dataset was built with (JSON-ready)."""
        return {}

    def stored_files(self, name: str) -> tuple[tuple[Path, str], ...]:
        """The files ``load(name)`` reads, each with what it holds ('mesh' or 'cloud'), so a job can
        check their sizes before reading them; () for a generated shape."""
        return ()

    def __len__(self) -> int:
        return len(self.names())

    def __iter__(self) -> Iterator[Shape]:
        for name in self.names():
            yield self.load(name)

    def iter_safe(self) -> Iterator[tuple[str, Shape | MeshError]]:
        """Yield ``(name, shape)`` or ``(name, MeshError)`` for every shape: never stops on a bad one."""
        for name in self.names():
            try:
                yield name, self.load(name)
            except MeshError as exc:
                yield name, exc

    def describe(self) -> dict[str, Any]:
        """JSON-ready record for config.json: dataset name, options, size and shape names."""
        names = self.names()
        return {"dataset": self.name, "options": self.options(), "count": len(names), "names": names}

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self.options().items())
        return f"<{type(self).__name__} '{self.name}' ({len(self)} shapes; {opts})>"

    def _unknown_shape(self, name: str) -> DatasetError:
        names = self.names()
        shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        return DatasetError(f"dataset '{self.name}' has no shape '{name}' ({len(names)} shapes: {shown})")


#: The dataset registry: name -> Dataset subclass (or factory returning one).
DATASETS: Registry[Callable[..., Dataset]] = Registry("dataset", error=DatasetError)


def register_dataset(name: str) -> Callable:
    """Decorator: make a :class:`Dataset` subclass (or a factory returning one) available as ``name``."""

    def decorate(factory):
        DATASETS.register(name, factory)
        if isinstance(factory, type) and not factory.name:
            factory.name = name
        return factory

    return decorate


def available_datasets() -> list[str]:
    """Registered dataset names, in registration order."""
    return DATASETS.names()


def up_axis_of(name: str | None) -> str:
    """The up axis ('x', 'y', 'z') of the dataset registered as ``name``; '' when it states none, is
    unknown, or is a factory rather than a :class:`Dataset` subclass."""
    try:
        factory = DATASETS.get(DEFAULT_DATASET if name is None else name)
    except DatasetError:
        return ""
    return factory.up_axis if isinstance(factory, type) and issubclass(factory, Dataset) else ""


def get_dataset(name: str | None = None, **options: Any) -> Dataset:
    """Build the dataset registered as ``name`` (default 'builtin') with its options.

    Unknown names and options raise :class:`DatasetError` (a ValueError) with one line listing the
    known ones; a missing data directory or list file raises :class:`DatasetNotFoundError`.
    """
    name = DEFAULT_DATASET if name is None else name
    factory = DATASETS.get(name)
    params = inspect.signature(factory).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        accepted = [k for k, p in params.items() if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
        unknown = sorted(set(options) - set(accepted))
        if unknown:
            raise DatasetError(
                f"dataset '{name}' has no option {', '.join(repr(u) for u in unknown)} "
                f"(options: {', '.join(accepted)})"
            )
    return factory(**options)


# -- option helpers shared by the datasets -------------------------------------------------------


def as_int(value: Any, option: str, minimum: int | None = None, allow_none: bool = False) -> int | None:
    """An integer option (strings from a CLI accepted); one-line DatasetError otherwise."""
    if value is None or (isinstance(value, str) and value.strip().lower() in ("", "none")):
        if allow_none:
            return None
        raise DatasetError(f"option '{option}' needs an integer, got {value!r}")
    try:
        number = int(value)
        if isinstance(value, float) and number != value:
            raise ValueError
    except (TypeError, ValueError):
        raise DatasetError(f"option '{option}' needs an integer, got {value!r}") from None
    if minimum is not None and number < minimum:
        raise DatasetError(f"option '{option}' must be >= {minimum}, got {number}")
    return number


def as_bool(value: Any, option: str) -> bool:
    """A boolean option; accepts bools, 0/1 and the strings true/false/yes/no/on/off."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in ("true", "yes", "on", "1", "false", "no", "off", "0"):
        return value.strip().lower() in ("true", "yes", "on", "1")
    raise DatasetError(f"option '{option}' needs true or false, got {value!r}")


def existing_dir(path: Any, dataset: str) -> Path:
    """The data directory option as a Path; DatasetNotFoundError (one line) when absent."""
    if path is None or str(path) == "":
        raise DatasetError(f"dataset '{dataset}' needs the option data_dir (a folder of mesh files)")
    path = Path(path).expanduser()
    if not path.exists():
        raise DatasetNotFoundError(f"dataset '{dataset}': data_dir {path} does not exist")
    if not path.is_dir():
        raise DatasetNotFoundError(f"dataset '{dataset}': data_dir {path} is not a directory")
    return path


def select_subset(names: list[str], limit: int | None, seed: int | None) -> list[str]:
    """``limit`` names out of ``names``: the first ones, or (with a seed) a seeded random subset
    drawn with ``numpy.random.default_rng(seed)`` and kept in the original order."""
    if limit is None or limit >= len(names):
        return list(names)
    if seed is None:
        return list(names[:limit])
    chosen = np.sort(np.random.default_rng(seed).choice(len(names), size=limit, replace=False))
    return [names[i] for i in chosen]
