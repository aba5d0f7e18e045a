"""Duplicate points: rows at one position are denoised as one point (docs/DECISIONS.md,
"Duplicates").

Scanners record some positions twice or more (overlapping strips, repeated returns, coordinates
quantised to a grid). Left in, each copy would count as a neighbour at distance zero: the lists
would span fewer positions than they hold, and the mean spacing, the noise probe and the region
radius would shrink with the share of copies. So the rows at one position are merged into their
first row before anything else, and every copy takes its result. A position is a row's exact
coordinates; with a tolerance ``t > 0`` (in the cloud's units) it is the cube of edge ``t`` the
row falls in, ``floor((p - low) / t)`` on every axis from the bounding box's low corner
``low``. Rows at different positions never merge, however close.

Each row's Morton code (the grid of :func:`pssd_fast.graph.morton_cells`) is that of its
position (the row itself, or its cube's low corner), so rows at one position share a code: once
sorted by code, they sit in one run of equal codes, where their coordinates tell them apart.
"""
import numbers

import numpy as np

from .graph import MORTON_BITS, bounds, code_order, grid_codes


def check_tolerance(value):
    """``value`` as a tolerance: a finite float of at least 0 (``duplicate_tolerance``)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"duplicate_tolerance must be a real number; got {value!r}")
    value = float(value)
    if not (np.isfinite(value) and value >= 0.0):
        raise ValueError(f"duplicate_tolerance must be a finite distance of at least 0, in the "
                         f"cloud's units (0: exact copies only); got {value}")
    return value


def keys(points, low, tolerance):
    """The position each of ``points`` merges by: its coordinates (``tolerance`` 0), else
    the index ``floor((p - low) / tolerance)`` of its cube on each axis (as floats)."""
    return points if tolerance == 0.0 else np.floor((points - low) / tolerance)


def codes(points, low, high, tolerance):
    """The Morton code of each row's position (:func:`keys`) in the grid of
    :func:`pssd_fast.graph.morton_cells` over the bounding box ``low``, ``high``: the row's
    own code for ``tolerance`` 0, else its cube's low corner's (within the box)."""
    extent = float((high - low).max())
    scale = (2**MORTON_BITS - 1) / extent if extent > 0.0 else 0.0
    if tolerance != 0.0:
        if extent >= tolerance * 2.0**52:
            # Beyond, the cubes' indices are no longer whole floats (or overflow): rows more
            # than the tolerance apart could share one.
            raise ValueError(f"duplicate_tolerance {tolerance} is too small for a cloud "
                             f"{extent} across (at most 2**52 cubes along a side); pass 0 "
                             f"to merge exact copies only")
        points = np.minimum(low + keys(points, low, tolerance) * tolerance, high)
    return grid_codes(points, low, scale)


def merged(sorted_codes, key):
    """Rows sorted by their :func:`codes` (ties in input order) grouped by position: for each
    row, the row (in that order) its group's first, or None where no two rows share one.
    ``key(at)``: the :func:`keys` of the rows at positions ``at`` (only rows that share a
    code with another are compared)."""
    n = sorted_codes.shape[0]
    same = sorted_codes[1:] == sorted_codes[:-1]
    shared = np.zeros(n, np.bool_)
    shared[1:] |= same
    shared[:-1] |= same
    at = np.flatnonzero(shared)
    if not at.shape[0]:
        return None
    rows, found = at, key(at)
    code = sorted_codes[at]
    new = np.empty(rows.shape[0], np.bool_)
    new[0] = True
    new[1:] = (code[1:] != code[:-1]) | (found[1:] != found[:-1]).any(axis=1)
    if (new[1:] & (code[1:] == code[:-1])).any():
        # Two positions in a run of one code (closer than a cell of the grid): sorted by
        # position, stably, so that each position's rows sit side by side in their order.
        by = np.lexsort((found[:, 2], found[:, 1], found[:, 0], code))
        rows, found, code = rows[by], found[by], code[by]
        new[1:] = (code[1:] != code[:-1]) | (found[1:] != found[:-1]).any(axis=1)
    if new.all():
        return None
    into = np.arange(n)
    into[rows] = rows[np.flatnonzero(new)[np.cumsum(new) - 1]]
    return into


def ordered(points, tolerance=0.0):
    """The distinct positions of ``points`` in Morton order, and the position of each row.

    Parameters
    ----------
    points : (n, 3) float64
    tolerance : float, default 0
        0: rows merge where their coordinates are equal. ``t > 0``: where they fall in one
        cube of edge ``t`` (in the cloud's units): ``floor((p - low) / t)`` agrees on every
        axis, ``low`` the bounding box's low corner.

    Returns
    -------
    order : (m,) int64
        The first row of each distinct position, along the Morton curve of the positions
        (:func:`codes`; ties in input order); with ``tolerance`` 0 and no two rows at one
        position, the whole :func:`pssd_fast.graph.morton_order`.
    groups : (n,) int64 or None
        For each row, the index in ``order`` of the row it was merged into; None where no two
        rows share a position.
    """
    low, high = bounds(points)
    found = codes(points, low, high, tolerance)
    order = code_order(found)
    into = merged(found[order], lambda at: keys(points[order[at]], low, tolerance))
    if into is None:
        return order, None
    first = into == np.arange(into.shape[0])
    groups = np.empty(into.shape[0], np.int64)
    groups[order] = (np.cumsum(first) - 1)[into]
    return order[first], groups
