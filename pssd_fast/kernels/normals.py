"""PCA normals over the kNN lists (docs/ALGORITHM.md, step 0), and their shifted variant at
sharp edges (docs/ALGORITHM.md, "Shifted normals")."""
import math

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


@helper
def eigen_scratch():
    """Scratch for :func:`list_eigen`, once per chunk of points: the covariance, its
    eigenvalues, its eigenvectors and the centroid."""
    return np.empty((3, 3)), np.empty(3), np.empty((3, 3)), np.empty(3)


@helper
def list_eigen(points, indptr, indices, i, skip, cov, w, v, centre):
    """Eigenvalues ``w`` (ascending) and eigenvectors ``v`` (columns) of the covariance of the
    neighbour list of point ``i``, and its centroid relative to ``points[i]`` into ``centre``
    (:func:`neighbourhood_covariance`, the first ``skip`` entries left out)."""
    neighbourhood_covariance(points, indptr, indices, i, skip, cov, centre)
    sym3_eigh(cov, w, v)


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
        cov, w, v, centre = eigen_scratch()
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            list_eigen(points, indptr, indices, i, 0, cov, w, v, centre)
            degenerate[i] = not (w[1] > DEGENERATE_RATIO * w[2])
            nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
            if nx * hints[i, 0] + ny * hints[i, 1] + nz * hints[i, 2] < 0.0:
                nx, ny, nz = -nx, -ny, -nz
            normals[i, 0] = nx
            normals[i, 1] = ny
            normals[i, 2] = nz


@parallel_kernel
def list_planes(points, indptr, indices, hints, centres, normals, variation, spread):
    """The PCA plane of each neighbour list and how well the list fits it: the normals of
    :func:`pca_normals`, and what the shifted normals need besides.

    Parameters
    ----------
    points : (n, 3) float64
    indptr, indices : CSR neighbour graph
    hints : (n, 3) float64
        Orientation hints, as in :func:`pca_normals`.
    centres : (n, 3) float64
        Output: the list's centroid relative to ``points[i]``.
    normals : (n, 3) float64
        Output: the unit normal of the list's plane, :func:`pca_normals`'s.
    variation : (n,) float64
        Output: the surface variation ``w0 / (w0 + w1 + w2)`` of the covariance's eigenvalues
        (ascending); ``inf`` where the list is collinear or coincident (no plane: where
        :func:`pca_normals` flags it degenerate).
    spread : (n,) float64
        Output: the RMS distance of the list to its plane, ``sqrt(w0 / count)``.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        cov, w, v, centre = eigen_scratch()
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            list_eigen(points, indptr, indices, i, 0, cov, w, v, centre)
            lowest = max(w[0], 0.0)
            total = lowest + w[1] + w[2]
            planar = w[1] > DEGENERATE_RATIO * w[2] and total > 0.0
            variation[i] = lowest / total if planar else np.inf
            spread[i] = math.sqrt(lowest / (indptr[i + 1] - indptr[i]))
            nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
            if nx * hints[i, 0] + ny * hints[i, 1] + nz * hints[i, 2] < 0.0:
                nx, ny, nz = -nx, -ny, -nz
            normals[i, 0], normals[i, 1], normals[i, 2] = nx, ny, nz
            for d in range(3):
                centres[i, d] = centre[d]


@parallel_kernel
def shifted_normals(points, indptr, indices, hints, centres, normals, variation, spread,
                    candidates, tolerance, out):
    """Each point's normal from the flattest plane among the lists of its first neighbours
    that passes near it (the lists of points beside a sharp edge do not reach across it).

    Parameters
    ----------
    points : (n, 3) float64
    indptr, indices : CSR neighbour graph (each list starts with the point itself)
    hints : (n, 3) float64
        The points' own oriented normals: the sign of each output, and the output where no
        candidate qualifies.
    centres, normals, variation, spread : outputs of :func:`list_planes` on the same graph
    candidates : int
        How many of each list's first entries are candidates.
    tolerance : float
        A candidate ``j`` qualifies when the distance of ``points[i]`` to its plane is at most
        ``tolerance * spread[j]``; of those, the one with the least ``variation`` wins (the
        first in list order on a tie).
    out : (n, 3) float64
        Output: unit normals, signed to agree with ``hints``.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            start = indptr[i]
            count = min(candidates, indptr[i + 1] - start)
            best = -1
            least = np.inf
            for t in range(count):
                j = indices[start + t]
                if not variation[j] < least:
                    continue
                # Distance of point i to the plane through j's centroid, relative to point j.
                dist = ((points[i, 0] - points[j, 0] - centres[j, 0]) * normals[j, 0]
                        + (points[i, 1] - points[j, 1] - centres[j, 1]) * normals[j, 1]
                        + (points[i, 2] - points[j, 2] - centres[j, 2]) * normals[j, 2])
                if abs(dist) <= tolerance * spread[j]:
                    best = j
                    least = variation[j]
            if best < 0:
                out[i, 0], out[i, 1], out[i, 2] = hints[i, 0], hints[i, 1], hints[i, 2]
                continue
            nx, ny, nz = normals[best, 0], normals[best, 1], normals[best, 2]
            if nx * hints[i, 0] + ny * hints[i, 1] + nz * hints[i, 2] < 0.0:
                nx, ny, nz = -nx, -ny, -nz
            out[i, 0], out[i, 1], out[i, 2] = nx, ny, nz
