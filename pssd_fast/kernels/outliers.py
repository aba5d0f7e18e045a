"""Per-point measures of how far a point lies off the surface its neighbours sample."""
import math

from numba import prange

from .config import CHUNK, parallel_kernel
from .normals import eigen_scratch, list_eigen


@parallel_kernel
def plane_offsets(points, indptr, indices, offsets):
    """Distance from each point to the least-squares plane of its neighbours, itself left out.

    Parameters
    ----------
    points : (n, 3) float64
    indptr, indices : CSR neighbour graph (each list starting with the point itself)
    offsets : (n,) float64
        Output: ``|(p_i - c_i) . m_i|``, with ``c_i`` the centroid of the other list members and
        ``m_i`` the smallest eigenvector of their covariance. Leaving the point out keeps an
        outlier from pulling the plane towards itself. A collinear or coincident rest gives
        an arbitrary but deterministic plane through ``c_i``.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        cov, w, v, centre = eigen_scratch()
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            list_eigen(points, indptr, indices, i, 1, cov, w, v, centre)
            offsets[i] = math.fabs(centre[0] * v[0, 0] + centre[1] * v[1, 0]
                                   + centre[2] * v[2, 0])
