"""Bilateral filters: of normals (docs/ALGORITHM.md step 3, eq. (4)) and of points (the BIL
baseline)."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .graph import max_degree
from .linalg import store_unit

# Below this spread (radians) all normals of a list agree and the filter leaves n_i unchanged.
MIN_SPREAD = 1e-12


@helper
def _filter_point(i, points, normals, indptr, indices, dist2, angle, out):
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    nix, niy, niz = normals[i, 0], normals[i, 1], normals[i, 2]
    start = indptr[i]
    count = indptr[i + 1] - start
    r2 = 0.0
    mean = 0.0
    for t in range(count):
        j = indices[start + t]
        dx = points[j, 0] - px
        dy = points[j, 1] - py
        dz = points[j, 2] - pz
        d2 = dx * dx + dy * dy + dz * dz
        r2 = max(r2, d2)
        dist2[t] = d2
        # Angle after flipping n_j to agree with n_i.
        a = math.acos(min(abs(nix * normals[j, 0] + niy * normals[j, 1] + niz * normals[j, 2]),
                          1.0))
        angle[t] = a
        mean += a
    mean /= count
    var = 0.0
    for t in range(count):
        var += (angle[t] - mean) ** 2
    spread = math.sqrt(var / count)
    if not spread > MIN_SPREAD:
        out[i, 0] = nix
        out[i, 1] = niy
        out[i, 2] = niz
        return
    # sigma_c = r_i / 2, sigma_s = spread: exp(-x^2 / (2 sigma^2)).
    inv_c = 2.0 / r2 if r2 > 0.0 else 0.0
    inv_s = 0.5 / (spread * spread)
    sx = sy = sz = 0.0
    for t in range(count):
        j = indices[start + t]
        wgt = math.exp(-dist2[t] * inv_c - angle[t] * angle[t] * inv_s)
        nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
        if nix * nx + niy * ny + niz * nz < 0.0:
            wgt = -wgt
        sx += wgt * nx
        sy += wgt * ny
        sz += wgt * nz
    store_unit(out, i, sx, sy, sz, nix, niy, niz)


@parallel_kernel
def filter_normals(points, normals, indptr, indices, out):
    """Bilateral filter of the normals over each neighbour list, eq. (4).

    Parameters
    ----------
    points, normals : (n, 3) float64
        Positions and unit normals ``n_i``.
    indptr, indices : CSR neighbour graph (each list contains the point itself)
    out : (n, 3) float64
        Output filtered unit normals ``n*_i``, oriented like ``n_i``.

    Notes
    -----
    ``n*_i = normalize(sum_j w_c(|p_j - p_i|) w_s(alpha_j) n_j)`` with neighbour normals flipped
    to agree with ``n_i``, ``alpha_j = acos(n_i . n_j)``, ``sigma_c = r_i / 2`` (``r_i`` the
    distance to the farthest list member; ``w_c = 1`` when it is 0) and ``sigma_s`` the population
    standard deviation of the ``alpha_j``. Where ``sigma_s`` is (numerically) zero, or the sum
    vanishes, ``n*_i = n_i``.
    """
    n = points.shape[0]
    longest = max_degree(indptr)
    for c in prange((n + CHUNK - 1) // CHUNK):
        dist2 = np.empty(longest)
        angle = np.empty(longest)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            _filter_point(i, points, normals, indptr, indices, dist2, angle, out)


@helper
def _bil_point(i, points, normals, indptr, indices, sigma_c, sigma_s, heights, out):
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
    start = indptr[i]
    count = indptr[i + 1] - start
    r2 = 0.0
    mean = 0.0
    for t in range(count):
        j = indices[start + t]
        dx = points[j, 0] - px
        dy = points[j, 1] - py
        dz = points[j, 2] - pz
        r2 = max(r2, dx * dx + dy * dy + dz * dz)
        h = nx * dx + ny * dy + nz * dz
        heights[t] = h
        mean += h
    mean /= count
    if sigma_s > 0.0:
        spread = sigma_s
    else:
        var = 0.0
        for t in range(count):
            var += (heights[t] - mean) ** 2
        spread = math.sqrt(var / count)
    if sigma_c > 0.0:
        inv_c = 0.5 / (sigma_c * sigma_c)
    else:
        inv_c = 2.0 / r2 if r2 > 0.0 else 0.0
    inv_s = 0.5 / (spread * spread) if spread > 0.0 else 0.0
    total = 0.0
    weight = 0.0
    for t in range(count):
        j = indices[start + t]
        dx = points[j, 0] - px
        dy = points[j, 1] - py
        dz = points[j, 2] - pz
        h = heights[t]
        wgt = math.exp(-(dx * dx + dy * dy + dz * dz) * inv_c - h * h * inv_s)
        total += wgt * h
        weight += wgt
    step = total / weight
    out[i, 0] = px + step * nx
    out[i, 1] = py + step * ny
    out[i, 2] = pz + step * nz


@parallel_kernel
def filter_points(points, normals, indptr, indices, sigma_c, sigma_s, out):
    """Bilateral point filter, the BIL baseline of Section 5 (after Fleishman et al. 2003).

    Parameters
    ----------
    points, normals : (n, 3) float64
        Positions and unit normals ``n_i``.
    indptr, indices : CSR neighbour graph (each list contains the point itself)
    sigma_c : float
        Spatial width; 0 or less means per point ``r_i / 2`` (``r_i`` the list radius).
    sigma_s : float
        Range width over the heights ``t_j``; 0 or less means per point the population
        standard deviation of the ``t_j``.
    out : (n, 3) float64
        Output ``p*_i = p_i + n_i sum_j w_c w_s t_j / sum_j w_c w_s`` with
        ``t_j = n_i . (p_j - p_i)``.

    Notes
    -----
    A zero spread (all heights equal) or a zero list radius makes that weight 1; the point
    itself (``t = 0``, weight 1) keeps the sum of weights positive.
    """
    n = points.shape[0]
    longest = max_degree(indptr)
    for c in prange((n + CHUNK - 1) // CHUNK):
        heights = np.empty(longest)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            _bil_point(i, points, normals, indptr, indices, sigma_c, sigma_s, heights, out)
