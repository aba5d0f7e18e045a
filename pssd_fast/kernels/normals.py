"""PCA normals over the kNN lists (docs/ALGORITHM.md, step 0)."""
import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .linalg import DEGENERATE_RATIO, set_sym3, sym3_eigh


@helper
def neighbourhood_covariance(points, indptr, indices, i, skip, cov, centre):
    """Covariance of the neighbour list of point ``i`` about its centroid, into ``cov``, and
    the centroid relative to ``points[i]`` into ``centre``; the first ``skip`` list entries
    (the point itself) are left out.

    Coordinates are taken relative to ``points[i]`` so that large offsets (georeferenced scans)
    cost no precision.
    """
    start = indptr[i] + skip
    count = indptr[i + 1] - start
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    cx = cy = cz = 0.0
    for t in range(start, start + count):
        j = indices[t]
        cx += points[j, 0] - px
        cy += points[j, 1] - py
        cz += points[j, 2] - pz
    cx /= count
    cy /= count
    cz /= count
    centre[0], centre[1], centre[2] = cx, cy, cz
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0
    for t in range(start, start + count):
        j = indices[t]
        dx = points[j, 0] - px - cx
        dy = points[j, 1] - py - cy
        dz = points[j, 2] - pz - cz
        c00 += dx * dx
        c01 += dx * dy
        c02 += dx * dz
        c11 += dy * dy
        c12 += dy * dz
        c22 += dz * dz
    set_sym3(cov, c00, c01, c02, c11, c12, c22)


@parallel_kernel
def pca_normals(points, indptr, indices, hints, normals, degenerate):
    """Unit normals by PCA of each neighbour list, oriented to agree with ``hints``.

    Parameters
    ----------
    points : (n, 3) float64
    indptr, indices : CSR neighbour graph
    hints : (n, 3) float64
        Orientation hints: ``normals[i]`` is flipped when ``normals[i] . hints[i] < 0``.
    normals : (n, 3) float64
        Output: eigenvector of the smallest eigenvalue of the covariance about the centroid.
    degenerate : (n,) bool
        Output: True where the neighbourhood is collinear or coincident (second eigenvalue at
        most ``DEGENERATE_RATIO`` times the largest); the normal there is an arbitrary but
        deterministic unit vector perpendicular to the line (or ``(1, 0, 0)`` for a point).
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        cov = np.empty((3, 3))
        w = np.empty(3)
        v = np.empty((3, 3))
        centre = np.empty(3)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            neighbourhood_covariance(points, indptr, indices, i, 0, cov, centre)
            sym3_eigh(cov, w, v)
            degenerate[i] = not (w[1] > DEGENERATE_RATIO * w[2])
            nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
            if nx * hints[i, 0] + ny * hints[i, 1] + nz * hints[i, 2] < 0.0:
                nx, ny, nz = -nx, -ny, -nz
            normals[i, 0] = nx
            normals[i, 1] = ny
            normals[i, 2] = nz
