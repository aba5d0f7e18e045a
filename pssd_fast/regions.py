"""Which items a tile's task reads: its own, then every other item near them (its halo).

A tile's own items are runs of a Morton curve; a single box around them may hold several times
their volume, so the tile is described by the boxes of :data:`PIECES` consecutive runs, each
widened by the halo's width.
"""
import numpy as np

from .graph import bounds, near_centres

#: A tile's halo is the items near the boxes of this many runs of its own.
PIECES = 32


def boxes(points):
    """The bounding boxes ``(p, 2, 3)`` of up to :data:`PIECES` consecutive runs of
    ``points``, as even as can be."""
    ends = np.linspace(0, points.shape[0], min(PIECES, points.shape[0]) + 1).astype(np.int64)
    return np.stack([np.stack(bounds(points[a:b])) for a, b in zip(ends[:-1], ends[1:])])


def widened(region, width):
    """The boxes ``region`` grown by ``width`` on every side."""
    return region + np.array([-width, width])[None, :, None]


def near(points, centres, radius):
    """The mask of ``points`` within ``radius`` of any of ``centres`` (a hair more: a halo may
    hold more than it needs, never less)."""
    return near_centres(points, centres, radius * (1.0 + 1e-9))
