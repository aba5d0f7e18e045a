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


def binned(codes, split, weights=None):
    """The sparse histogram ``(firsts, counts)`` of the ``codes`` (uint64) inside the ranges
    ``split`` of :func:`parts`, each range's binned by its finer shift, each bin named by its
    first code; the codes outside every range left out. ``weights``: each code's count (1)."""
    starts, shifts, finer = split
    at = np.searchsorted(starts, codes, side="right") - 1
    inside = at >= 0
    at = np.maximum(at, 0)
    inside &= ((codes - starts[at]) >> shifts[at]) == 0  # wraps below the first: masked above
    at = at[inside]
    keys = (codes[inside] >> finer[at]) << finer[at]
    found, inverse = np.unique(keys, return_inverse=True)
    counts = np.bincount(inverse, None if weights is None else weights[inside], found.shape[0])
    return found, counts.astype(np.int64)


def parts(summed, shift, most, refine):
    """The first code of each part of the codes whose first bits (``code >> shift``) the
    histogram ``summed`` counts: runs of consecutive codes of at most ``most`` points (more
    only where they share one code). A bin of more than ``most`` points is split by
    ``refine(split)``, which returns the sparse histograms (:func:`binned`) of the codes in
    the ranges ``split`` (first codes, shifts of their widths and the next
    :data:`PREFIX_BITS` bits' shifts, all uint64); so a far point, which leaves every other
    in one bin of the first bits, costs a pass or two over the codes, not the tiles' size."""
    found = np.flatnonzero(summed)
    counts = summed[found]
    shifts = np.full(found.shape[0], shift, np.uint64)
    firsts = found.astype(np.uint64) << shifts
    while True:
        split = (counts > most) & (shifts > 0)
        if not split.any():
            break
        finer = np.maximum(shifts[split].astype(np.int64) - PREFIX_BITS, 0).astype(np.uint64)
        pieces = list(refine((firsts[split], shifts[split], finer)))
        keys = np.concatenate([piece[0] for piece in pieces])
        keys, inverse = np.unique(keys, return_inverse=True)
        sub = np.bincount(inverse, np.concatenate([piece[1] for piece in pieces]),
                          keys.shape[0]).astype(np.int64)
        sub_shifts = finer[np.searchsorted(firsts[split], keys, side="right") - 1]
        firsts = np.concatenate((firsts[~split], keys))
        order = np.argsort(firsts, kind="stable")
        firsts = firsts[order]
        counts = np.concatenate((counts[~split], sub))[order]
        shifts = np.concatenate((shifts[~split], sub_shifts))[order]
    starts = []
    filled = 0
    for b, count in enumerate(counts.tolist()):
        if not starts or (filled and filled + count > most):
            starts.append(b)
            filled = 0
        filled += count
    return firsts[np.array(starts, np.int64)]


def part_of(firsts, codes):
    """The part (:func:`parts`) of each of the ``codes``."""
    return np.searchsorted(firsts, codes, side="right") - 1
