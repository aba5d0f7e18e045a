"""Which items a tile's task reads: its own, then every other item near them (its halo).

A tile's own items are runs of a Morton curve; a single box around them may hold several times
their volume, so the tile is described by the boxes of :data:`PIECES` consecutive runs, each
widened by the halo's width.
"""
import numpy as np

from .graph import MORTON_BITS, bounds, cell_keys, near_centres

#: A tile's halo is the items near the boxes of this many runs of its own.
PIECES = 32
#: Tiles (and out of core, buckets) are cut between bins of the first this many bits of their
#: points' codes: a cut needs only a histogram of those bits, which tasks sum over chunks.
PREFIX_BITS = 21


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


def code_shifts(high, low, edge):
    """The shifts of the cell codes (:func:`pssd_fast.graph.cell_keys`) of points up to
    ``high`` on the grid of ``edge`` from ``low``: the codes' own, from the largest cell
    coordinate (the high corner's, rounded as each point's is), and the one that leaves their
    first :data:`PREFIX_BITS` bits (a Morton code grows with each coordinate, so the high
    corner's code has the bits of the largest)."""
    top = int(((high - low) * (1.0 / edge)).max())
    shift = max(0, top.bit_length() - MORTON_BITS)
    return shift, prefix_shift(cell_keys(high[None, :], low, edge, shift)[0][0])


def prefix_shift(largest):
    """The shift that leaves the first :data:`PREFIX_BITS` bits of codes up to ``largest``."""
    return max(0, int(largest).bit_length() - PREFIX_BITS)


def histogram(sparse):
    """The histogram of :data:`PREFIX_BITS` bits summed from sparse ``(bins, counts)`` pairs."""
    summed = np.zeros(1 << PREFIX_BITS, np.int64)
    for found, counts in sparse:
        summed[found.astype(np.int64)] += counts
    return summed


def cuts(summed, most):
    """The first bin of each part of the histogram ``summed``: consecutive bins, at most
    ``most`` points a part (a fuller bin alone)."""
    firsts = []
    filled = 0
    for b in np.flatnonzero(summed):
        if not firsts or (filled and filled + summed[b] > most):
            firsts.append(b)
            filled = 0
        filled += summed[b]
    return np.array(firsts, np.int64)


def part_of(firsts, found):
    """The part (:func:`cuts`) of each of the bins ``found`` (bins that hold points)."""
    return np.searchsorted(firsts, found.astype(np.int64), side="right") - 1
