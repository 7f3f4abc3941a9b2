"""Errors a point-cloud method raises for an input it cannot reconstruct from."""

from __future__ import annotations


class TooFewPointsError(ValueError):
    """The cloud has fewer points than the method's neighbourhoods hold (one line: the method, the
    count and what it needs). A whole shape with so few points fails its job with this line; a
    block's window with so few points (:func:`methods.pointcloud.blocks.window_piece`) gives no
    surface, like a window below its ``min_points``."""

    def __init__(self, method: str, points: int, needed: int, what: str):
        super().__init__(f"{method}: {points} points, fewer than {what}'s {needed} neighbours")
        self.points, self.needed = points, needed
