"""What a method's trained weights were trained on, so a result row can say whether its shape was
among them (``seen_in_training``): a shape seen in training scores what the network may have
memorised, not what it generalises to.

A :class:`TrainingRecord` matches a shape by its ABC object id (the 8 leading digits of an ABC file
name, e.g. NDC's published weights: ABC 00000002-00007903) or by its content hash (the canonical
mesh, :attr:`datasets.io.Shape.content_hash`; our own networks, whose training shapes are known).
A soup of several ABC parts (``abc-nonmanifold``, ``A+B``) is seen when any part is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["TrainingRecord", "abc_ids"]

_ABC_ID = re.compile(r"^(\d{8})(?!\d)")


def abc_ids(name: str) -> list[int]:
    """The ABC object ids a shape name carries: the 8 leading digits of each ``+``-separated part
    (``'00000006_0'`` -> [6]; ``'00000003_ab+00010218_cd'`` -> [3, 10218]; ``'bracket'`` -> [])."""
    found = (_ABC_ID.match(part.strip()) for part in str(name).split("+"))
    return [int(m.group(1)) for m in found if m]


@dataclass(frozen=True)
class TrainingRecord:
    """The training set of a method's weights, as far as shapes can be matched against it.

    description : one line for captions (whose weights, trained on what).
    abc_ranges : inclusive ranges of ABC object ids the weights were trained on.
    content_hashes : content hashes of the training shapes (canonical meshes); None when the
        weights do not record them (then whether a shape was seen is unknown).
    """

    description: str
    abc_ranges: tuple[tuple[int, int], ...] = ()
    content_hashes: frozenset[str] | None = frozenset()

    def saw(self, name: str, content_hash: str) -> bool | None:
        """Whether the shape ``name`` (content hash ``content_hash``) is in this training set; None
        when that cannot be known (no recorded hashes and no matching id range)."""
        if any(lo <= i <= hi for i in abc_ids(name) for lo, hi in self.abc_ranges):
            return True
        if self.content_hashes is None:
            return None
        return content_hash in self.content_hashes
