"""Per-point measures of how far a point lies off the surface its neighbours sample."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, parallel_kernel
from .graph import max_degree
from .noise import median_abs
from .normals import eigen_scratch, list_eigen


@parallel_kernel
def plane_offsets(points, indptr, indices, offsets, spreads):
    """Distance from each point to the least-squares plane of its neighbours, itself left out,
    and how far those neighbours lie from that plane.

    Parameters
    ----------
    points : (n, 3) float64
    indptr, indices : CSR neighbour graph (each list starting with the point itself, at least
        one other)
    offsets : (n,) float64
        Output: ``|(p_i - c_i) . m_i|``, with ``c_i`` the centroid of the other list members and
        ``m_i`` the smallest eigenvector of their covariance. Leaving the point out keeps an
        outlier from pulling the plane towards itself. A collinear or coincident rest gives
        an arbitrary but deterministic plane through ``c_i``.
    spreads : (n,) float64
        Output: the median distance of the other members to that plane (a median, so that the
        few outliers among them do not widen it).
    """
    n = points.shape[0]
    longest = max_degree(indptr)
    for c in prange((n + CHUNK - 1) // CHUNK):
        cov, w, v, centre = eigen_scratch()
        heights = np.empty(max(longest - 1, 1))
        scratch = np.empty(max(longest - 1, 1))
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            list_eigen(points, indptr, indices, i, 1, cov, w, v, centre)
            nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
            offsets[i] = math.fabs(centre[0] * nx + centre[1] * ny + centre[2] * nz)
            # Members' heights above the plane through the centroid (relative to p_i).
            count = indptr[i + 1] - indptr[i] - 1
            for t in range(count):
                j = indices[indptr[i] + 1 + t]
                heights[t] = ((points[j, 0] - points[i, 0] - centre[0]) * nx
                              + (points[j, 1] - points[i, 1] - centre[1]) * ny
                              + (points[j, 2] - points[i, 2] - centre[2]) * nz)
            spreads[i] = median_abs(heights, count, scratch) if count > 0 else 0.0
