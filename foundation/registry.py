"""Name -> object registries with one "unknown X; known: ..." message (the project's one lookup rule).

Every named thing a user can pick on the command line (methods, datasets, budgets, metric presets,
executors, regression tiers) lives in a :class:`Registry`::

    METHODS = Registry("method")
    METHODS.register("sals", SALSMethod)
    METHODS.get("sals")            # -> SALSMethod
    METHODS.get("sal")             # ValueError: unknown method 'sal'; known methods: bof, sdf, udf, sals
    with METHODS.registered("toy", ToyMethod):   # tests: a temporary entry, removed on exit
        ...

Names keep their registration order unless an ``order`` key is given (e.g. a method's display order).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Generic, Iterator, TypeVar

T = TypeVar("T")


class UnknownNameError(ValueError):
    """A name that is not registered; the message lists the known names."""


class Registry(Generic[T]):
    """An ordered name -> object mapping with one error message for unknown names.

    Parameters
    ----------
    kind : what the entries are, singular ('method'); the message says "known methods: ...".
    error : exception class raised for unknown names (a ValueError subclass).
    loader : called once before the first lookup (e.g. imports the modules that register entries).
    order : sort key of an entry for :meth:`names` (default: registration order).
    """

    def __init__(self, kind: str, error: type[ValueError] = UnknownNameError,
                 loader: Callable[[], None] | None = None, order: Callable[[T], object] | None = None):
        self.kind = kind
        self.error = error
        self._loader = loader
        self._order = order
        self._entries: dict[str, T] = {}

    def _load(self) -> None:
        if self._loader is not None:
            loader, self._loader = self._loader, None
            loader()

    def register(self, name: str, obj: T) -> T:
        """Add ``obj`` under ``name``; registering a different object under a taken name raises."""
        if not name or not isinstance(name, str):
            raise ValueError(f"a {self.kind} needs a non-empty string name")
        if name in self._entries and self._entries[name] is not obj:
            raise ValueError(f"{self.kind} name '{name}' is registered twice")
        self._entries[name] = obj
        return obj

    def unregister(self, name: str) -> None:
        self._entries.pop(name, None)

    @contextmanager
    def registered(self, name: str, obj: T) -> Iterator[T]:
        """Register ``obj`` for the duration of a ``with`` block (tests, plugins tried out)."""
        self._load()
        self.register(name, obj)
        try:
            yield obj
        finally:
            self.unregister(name)

    def names(self) -> list[str]:
        """Registered names, in ``order`` (or registration order)."""
        self._load()
        names = list(self._entries)
        if self._order is not None:
            names.sort(key=lambda n: self._order(self._entries[n]))
        return names

    def unknown(self, name: str) -> ValueError:
        """The one-line error for an unknown name (for callers that validate before looking up)."""
        return self.error(f"unknown {self.kind} '{name}'; known {self.kind}s: {', '.join(self.names())}")

    def get(self, name: str) -> T:
        self._load()
        if name not in self._entries:
            raise self.unknown(name)
        return self._entries[name]

    __getitem__ = get

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    def items(self) -> list[tuple[str, T]]:
        return [(n, self._entries[n]) for n in self.names()]
