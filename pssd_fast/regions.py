"""Which items a tile's task reads: its own, then every other item near them (its halo).

A tile's own items are runs of a Morton curve; a single box around them may hold several times
their volume, so the tile is described by the boxes of :data:`PIECES` consecutive runs, each
widened by the halo's width.
"""
import numpy as np

from .graph import bounds

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


def within(points, region):
    """The mask of ``points`` inside any of the boxes ``region`` ``(p, 2, 3)``."""
    low, high = region[:, 0].min(axis=0), region[:, 1].max(axis=0)
    rows = np.flatnonzero(_inside(points, low, high))
    near = points[rows]
    hit = np.zeros(rows.shape[0], np.bool_)
    for low, high in region:
        hit |= _inside(near, low, high)
    inside = np.zeros(points.shape[0], np.bool_)
    inside[rows[hit]] = True
    return inside


def _inside(points, low, high):
    inside = (points[:, 0] >= low[0]) & (points[:, 0] <= high[0])
    for a in (1, 2):
        inside &= (points[:, a] >= low[a]) & (points[:, a] <= high[a])
    return inside

