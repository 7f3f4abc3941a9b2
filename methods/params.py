"""Typed method parameters: a method declares each extractor parameter as a :class:`Param`.

A parameter's type is its default's type (bool, int, float or str). Values from the command line
(``--method-param sals.normals=no``) or a config file are parsed against it, so a typo is refused
before any work starts instead of being read as the wrong thing:

* bool: ``true/false/yes/no/on/off/1/0`` (any case) or a real bool; anything else is refused
  (``bool('False')`` is True in Python: never used);
* int: an integer (``'4'``; not ``'4.5'``); float: any finite number (``'0.2'``, ``'1e-3'``);
* str: one of ``choices`` when given;
* ranges: ``gt``/``ge``/``lt``/``le`` bounds, e.g. a threshold in (0, 1) is ``Param(0.1, gt=0, lt=1)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

_TRUE = {"true", "yes", "on", "1"}
_FALSE = {"false", "no", "off", "0"}


class ParamError(ValueError):
    """A parameter value that does not parse or lies outside its range (one line)."""


@dataclass(frozen=True)
class Param:
    """One parameter: default (fixes the type), help text, optional bounds and choices."""

    default: Any
    help: str = ""
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    neural_only: bool = False  # read only by the neural field's query (the exact field ignores it)
    fit: bool = False  # read by the fit (its inputs, targets or loss): part of the fitted weights' cache key

    @property
    def kind(self) -> type:
        return type(self.default)

    def describe(self) -> str:
        """Type and allowed values, e.g. 'float in (0, 1)' or "str, one of 'fan4', 'quad2'"."""
        text = self.kind.__name__
        if self.choices:
            return f"{text}, one of " + ", ".join(repr(c) for c in self.choices)
        lo = f"({self.gt:g}" if self.gt is not None else (f"[{self.ge:g}" if self.ge is not None else None)
        hi = f"{self.lt:g})" if self.lt is not None else (f"{self.le:g}]" if self.le is not None else None)
        if lo or hi:
            text += f" in {lo or '(-inf'}, {hi or 'inf)'}"
        return text

    def parse(self, value: Any, name: str) -> Any:
        """``value`` as this parameter's type, checked; :class:`ParamError` names ``name`` otherwise."""
        kind = self.kind
        try:
            if kind is bool:
                out = self._bool(value)
            elif kind is int:
                if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                    raise ValueError
                out = int(value) if not isinstance(value, str) else int(value.strip())
            elif kind is float:
                if isinstance(value, bool):
                    raise ValueError
                out = float(value)
                if not math.isfinite(out):
                    raise ValueError
            else:
                out = str(value)
        except (TypeError, ValueError):
            raise ParamError(f"{name}={value!r}: expected {self.describe()}") from None
        if self.choices is not None and out not in self.choices:
            raise ParamError(f"{name}={value!r}: expected {self.describe()}")
        bounds = ((self.gt, lambda v, b: v > b), (self.ge, lambda v, b: v >= b),
                  (self.lt, lambda v, b: v < b), (self.le, lambda v, b: v <= b))
        if any(b is not None and not ok(out, b) for b, ok in bounds):
            raise ParamError(f"{name}={value!r}: expected {self.describe()}")
        return out

    @staticmethod
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


def with_overrides(base, overrides, params: dict[str, "Param"], what: str):
    """The frozen dataclass ``base`` with ``overrides`` applied, each typed and checked by its
    :class:`Param` in ``params`` (named ``what.NAME`` in messages); unknown names list the known ones."""
    import dataclasses

    if not overrides:
        return base
    unknown = sorted(set(overrides) - set(params))
    if unknown:
        raise ParamError(f"{what} has no setting '{unknown[0]}' that a run may change; known: {', '.join(sorted(params))}")
    return dataclasses.replace(base, **{k: params[k].parse(v, f"{what}.{k}") for k, v in overrides.items()})

