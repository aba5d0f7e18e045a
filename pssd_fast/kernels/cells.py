"""Means of the points sharing a grid cell: the cell means the default method iterates on
(docs/ALGORITHM.md, "Cells")."""
from numba import prange

from .config import parallel_kernel
from .linalg import store_unit


@parallel_kernel
def cell_means(points, normals, mass, order, starts, out, out_normals):
    """Mean point (and mean normal) of each cell, weighted by ``mass``.

    Parameters
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64 or (0, 3)
        Unit normals of ``points`` (signs may differ between neighbours), or no rows: then
        ``out_normals`` is left alone.
    mass : (n,) float64 or (0,)
        The weight of each point; no entries: every weight is 1.
    order : (n,) int64
        Rows of ``points`` grouped by cell: cell ``c`` holds ``order[starts[c]:starts[c + 1]]``.
    starts : (m + 1,) int64
    out : (m, 3) float64
        Output: the mean of each cell's points, summed in ``order``.
    out_normals : (m, 3) float64
        Output: the unit (weighted) mean of each cell's normals, each first turned to the side
        of the cell's first normal; the first normal itself where they cancel.
    """
    m = starts.shape[0] - 1
    with_normals = normals.shape[0] > 0
    with_mass = mass.shape[0] > 0
    for c in prange(m):
        sx = 0.0
        sy = 0.0
        sz = 0.0
        sw = 0.0
        for t in range(starts[c], starts[c + 1]):
            i = order[t]
            w = mass[i] if with_mass else 1.0
            sx += w * points[i, 0]
            sy += w * points[i, 1]
            sz += w * points[i, 2]
            sw += w
        out[c, 0] = sx / sw
        out[c, 1] = sy / sw
        out[c, 2] = sz / sw
        if with_normals:
            first = order[starts[c]]
            fx, fy, fz = normals[first, 0], normals[first, 1], normals[first, 2]
            sx = 0.0
            sy = 0.0
            sz = 0.0
            for t in range(starts[c], starts[c + 1]):
                i = order[t]
                sign = 1.0 if fx * normals[i, 0] + fy * normals[i, 1] + fz * normals[i, 2] >= 0.0 \
                    else -1.0
                if with_mass:
                    sign *= mass[i]
                sx += sign * normals[i, 0]
                sy += sign * normals[i, 1]
                sz += sign * normals[i, 2]
            store_unit(out_normals, c, sx, sy, sz, fx, fy, fz)
