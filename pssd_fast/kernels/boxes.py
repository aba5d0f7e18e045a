"""Which points lie in a tile's halo (:mod:`pssd_fast.regions`): inside any of a few boxes, or
within a distance of any of a set of centres."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel


@parallel_kernel
def inside_any(points, boxes, out):
    """Whether each point lies inside any of ``boxes``, faces included.

    Parameters
    ----------
    points : (n, 3) float64
    boxes : (p, 2, 3) float64
        Each box's low and high corner.
    out : (n,) bool
        Output: ``low <= p <= high`` on every axis for some box.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            x, y, z = points[i, 0], points[i, 1], points[i, 2]
            hit = False
            for b in range(boxes.shape[0]):
                if (boxes[b, 0, 0] <= x <= boxes[b, 1, 0] and boxes[b, 0, 1] <= y <= boxes[b, 1, 1]
                        and boxes[b, 0, 2] <= z <= boxes[b, 1, 2]):
                    hit = True
                    break
            out[i] = np.bool_(hit)


@helper
def _cell_index(keys, key):
    """The index of ``key`` in the ascending ``keys``, or -1."""
    lo, hi = 0, keys.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if keys[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo if lo < keys.shape[0] and keys[lo] == key else -1


@helper
def _slot(keys, dense, key):
    """The index of cell ``key`` among the centres' cells ``keys``, or -1: from the table
    ``dense`` of every cell's where it is given (not empty), else by binary search."""
    return dense[key] if dense.shape[0] else _cell_index(keys, key)


@parallel_kernel
def near_any(points, centres, low, inv_cell, dims, keys, starts, reached, dense, radius2, out):
    """Whether each point lies within ``sqrt(radius2)`` of any of ``centres``.

    Parameters
    ----------
    points : (n, 3) float64
    centres : (m, 3) float64
        Grouped by the key of their cell of a grid of edge ``1 / inv_cell`` (at least the
        radius) from ``low``: cell ``(x, y, z)`` has key ``(x * dims[1] + y) * dims[2] + z``.
    low : (3,) float64
    inv_cell : float
    dims : (3,) int64
        Cells per axis; every centre's cell and its neighbours lie within them.
    keys : (c,) int64
        The distinct keys of the centres' cells, ascending.
    starts : (c + 1,) int64
        ``centres[starts[t]:starts[t + 1]]`` lie in cell ``keys[t]``.
    reached : (r,) int64
        The keys of the centres' cells and of their neighbours, ascending: a point in no such
        cell is near no centre.
    dense : (nx * ny * nz,) int32 or (0,)
        For a small grid, each cell's index in ``keys``, -2 for a cell ``reached`` holds that
        is not one of them and -1 for the others: one lookup a point instead of binary
        searches (empty: the searches).
    radius2 : float
        The squared distance, included.
    out : (n,) bool
        Output.
    """
    n = points.shape[0]
    nx, ny, nz = dims[0], dims[1], dims[2]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            x, y, z = points[i, 0], points[i, 1], points[i, 2]
            fx = (x - low[0]) * inv_cell
            fy = (y - low[1]) * inv_cell
            fz = (z - low[2]) * inv_cell
            hit = False
            # Outside the grid (or not finite), or in a cell no centre reaches: near none.
            if 0.0 <= fx < nx and 0.0 <= fy < ny and 0.0 <= fz < nz:
                cx, cy, cz = int(math.floor(fx)), int(math.floor(fy)), int(math.floor(fz))
                key = (cx * ny + cy) * nz + cz
                if (dense[key] != -1) if dense.shape[0] else (_cell_index(reached, key) >= 0):
                    hit = _near_in_cells(centres, keys, starts, dense, cx, cy, cz, ny, nz, x, y,
                                         z, radius2)
            out[i] = np.bool_(hit)


@helper
def _near_in_cells(centres, keys, starts, dense, cx, cy, cz, ny, nz, x, y, z, radius2):
    """Whether a centre of cell ``(cx, cy, cz)`` or of a neighbour lies within the radius of
    ``(x, y, z)``."""
    for gx in range(cx - 1, cx + 2):
        for gy in range(cy - 1, cy + 2):
            for gz in range(cz - 1, cz + 2):
                t = _slot(keys, dense, (gx * ny + gy) * nz + gz)
                if t < 0:
                    continue
                for j in range(starts[t], starts[t + 1]):
                    dx = centres[j, 0] - x
                    dy = centres[j, 1] - y
                    dz = centres[j, 2] - z
                    if dx * dx + dy * dy + dz * dz <= radius2:
                        return True
    return False
