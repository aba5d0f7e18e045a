"""Duplicate points: rows at one position are denoised as one point (docs/DECISIONS.md,
"Duplicates").

Scanners record some positions twice or more (overlapping strips, repeated returns, coordinates
quantised to a grid). Left in, each copy would count as a neighbour at distance zero: the lists
would span fewer positions than they hold, and the mean spacing, the noise probe and the region
radius would shrink with the share of copies. So the rows that share a cell of the Morton grid
(``2**21 - 1`` cells along the longest side of the bounding box, so a few millionths of it
apart at most) are merged into their first row before anything else, and every copy takes its
result.
"""
import numpy as np

from .graph import morton_cells


def ordered(points):
    """The distinct positions of ``points`` in Morton order, and the position of each row.

    Parameters
    ----------
    points : (n, 3) float64

    Returns
    -------
    order : (m,) int64
        The first row of each distinct position (of each occupied cell of the Morton grid),
        along the Morton curve; the whole :func:`pssd_fast.graph.morton_order` where no two
        rows share a cell.
    groups : (n,) int64 or None
        For each row, the index in ``order`` of the row it was merged into; None where no two
        rows share a cell.
    """
    codes = morton_cells(points)
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    first = np.empty(codes.shape[0], np.bool_)
    first[:1] = True
    np.not_equal(codes[1:], codes[:-1], out=first[1:])
    if first.all():
        return order, None
    groups = np.empty(codes.shape[0], np.int64)
    groups[order] = np.cumsum(first) - 1
    return order[first], groups
