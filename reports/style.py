"""How methods are shown: their order and colours, from the method registry (``methods.base.METHODS``).

A registered method has an ``order`` and a ``color`` (its :class:`methods.base.Presentation`). A method the
registry does not know (e.g. from an older run) goes after the registered ones, in order of
appearance, and gets the next colour of :data:`PALETTE` that no shown method uses.
"""

from __future__ import annotations

from methods.base import METHODS, presentation

#: Fallback qualitative palette for methods outside the registry (and for runs in comparison plots).
PALETTE = ("#8367c7", "#6c757d", "#d1495b", "#00798c", "#edae49", "#66a182", "#2e4057", "#b07aa1")


def method_order(methods, preferred=()) -> list[str]:
    """``methods`` (unique, any order) in display order.

    Parameters
    ----------
    methods : iterable of method names, e.g. the ``method`` column of a results frame.
    preferred : the run's own order (``context['methods']``); those present come first, as given.

    Returns
    -------
    list of str
        ``preferred`` names present, then registered methods by their ``order``, then unknown
        ones in order of appearance.
    """
    present = list(dict.fromkeys(str(m) for m in methods))
    first = [m for m in dict.fromkeys(preferred) if m in present]
    rest = [m for m in present if m not in first]
    registered = sorted((m for m in rest if m in METHODS), key=lambda m: presentation(m).order)
    return first + registered + [m for m in rest if m not in METHODS]


def fit_owner(method: str) -> str:
    """The method whose fits ``method`` extracts (``sdf`` for ``sdf-ndc``: its ``fit_name``); itself
    when it fits its own network or the registry does not know it."""
    return METHODS.get(method).fit_name if method in METHODS else method


def method_colors(methods: list[str]) -> dict[str, str]:
    """{method: '#rrggbb'}: the registry's colour, else the next unused colour of :data:`PALETTE`."""
    colors = {m: presentation(m).color for m in methods if m in METHODS}
    spare = [c for c in PALETTE if c not in colors.values()] or list(PALETTE)
    unknown = [m for m in methods if m not in colors]
    colors.update({m: spare[i % len(spare)] for i, m in enumerate(unknown)})
    return {m: colors[m] for m in methods}
