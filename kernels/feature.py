"""Region-grown neighbourhoods and the normal voting tensor (ALGORITHM.md, step 2; Section 3)."""
import math

import numba
import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .linalg import set_sym3, sym3_eigh

# Below this squared length the tangential part of a neighbour's normal is taken as zero: the
# normal points along the connecting line and the vote cannot rotate it.
TINY = 1e-30


@helper
def grow_region(points, indptr, indices, i, radius2, n_vote, stamp, queue, dist2):
    """Breadth-first region growing of ``N_R(i)``; returns its size ``count``.

    Starting from ``i``, each member adds those of the first ``n_vote`` entries of its own
    neighbour list that lie within ``sqrt(radius2)`` of ``p_i`` and are not members yet.
    Members are left in ``queue[:count]`` in discovery order, their squared distances to
    ``p_i`` in ``dist2[:count]``. ``stamp`` (one entry per point) marks every point examined for
    ``i`` with the value ``i``, members and rejected candidates alike, so each candidate's
    distance is computed once and the marks never need clearing.
    """
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    queue[0] = i
    dist2[0] = 0.0
    stamp[i] = i
    count = 1
    head = 0
    while head < count:
        j = queue[head]
        head += 1
        start = indptr[j]
        for t in range(start, min(indptr[j + 1], start + n_vote)):
            cand = indices[t]
            if stamp[cand] == i:
                continue
            stamp[cand] = i
            dx = points[cand, 0] - px
            dy = points[cand, 1] - py
            dz = points[cand, 2] - pz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= radius2:
                queue[count] = cand
                dist2[count] = d2
                count += 1
    return count


@helper
def _vote(points, normals, i, queue, dist2, count, tensor, w, v, delta, alpha, beta):
    """Feature intensity of point ``i`` from the voted normals of its region ``queue[:count]``."""
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    nix, niy, niz = normals[i, 0], normals[i, 1], normals[i, 2]
    r2 = 0.0
    for t in range(count):
        r2 = max(r2, dist2[t])
    sigma = 2.0 * math.sqrt(r2) / 3.0
    inv_sigma = 1.0 / sigma if sigma > 0.0 else 0.0

    t00 = t01 = t02 = t11 = t12 = t22 = 0.0
    bx = by = bz = 0.0
    for t in range(count):
        j = queue[t]
        nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
        if nx * nix + ny * niy + nz * niz < 0.0:
            nx, ny, nz = -nx, -ny, -nz
        vv = dist2[t]
        if vv > 0.0:
            # w = (v x n) x v is the part of n perpendicular to v; n' = 2 (n . w) w / |w|^2 - n
            # reflects n's component along v (Page et al.'s vote of n_j at p_i along the arc).
            vx = px - points[j, 0]
            vy = py - points[j, 1]
            vz = pz - points[j, 2]
            vn = (vx * nx + vy * ny + vz * nz) / vv
            wx = nx - vn * vx
            wy = ny - vn * vy
            wz = nz - vn * vz
            ww = wx * wx + wy * wy + wz * wz
            if ww > TINY:
                nw = 2.0 * (nx * wx + ny * wy + nz * wz) / ww
                nx, ny, nz = nw * wx - nx, nw * wy - ny, nw * wz - nz
        u = math.exp(-math.sqrt(vv) * inv_sigma)
        t00 += u * nx * nx
        t01 += u * nx * ny
        t02 += u * nx * nz
        t11 += u * ny * ny
        t12 += u * ny * nz
        t22 += u * nz * nz
        bx += u * nx
        by += u * ny
        bz += u * nz
    set_sym3(tensor, t00, t01, t02, t11, t12, t22)
    sym3_eigh(tensor, w, v)
    v1 = w[2]
    v2 = max(w[1], 0.0)
    v3 = min(max(w[0], 0.0), v2)
    bn = math.sqrt(bx * bx + by * by + bz * bz)
    align = abs(bx * v[0, 2] + by * v[1, 2] + bz * v[2, 2]) / bn if bn > 0.0 else 0.0
    if align < delta:
        return 1.0
    if v3 > alpha * (v1 - v2) and v3 > beta * (v2 - v3):
        return 1.0
    return (v2 - v3) / v1 if v1 > 0.0 else 0.0


@parallel_kernel
def feature_intensity(points, normals, indptr, indices, radius, n_vote, delta, alpha, beta,
                      n_slots, out, region_size):
    """Feature intensity ``s_i`` of eq. (3) from the normal voting tensor over ``N_R(i)``.

    Parameters
    ----------
    points, normals : (n, 3) float64
        Positions and unit normals (only locally consistent orientation is needed: each
        neighbour's normal is flipped to agree with ``normals[i]`` first).
    indptr, indices : CSR neighbour graph, lists sorted by distance, each starting with itself
    radius : float
        ``R``: region members lie within ``R`` of ``p_i``.
    n_vote : int
        Length of the list prefix used for growing (the paper's 9 nearest neighbours).
    delta, alpha, beta : float
        Thresholds of eq. (3).
    n_slots : int
        Size of numba's thread pool (``numba.config.NUMBA_NUM_THREADS``): one scratch row per
        thread, indexed by ``numba.get_thread_id()``.
    out : (n,) float64
        Output ``s_i`` in [0, 1].
    region_size : (n,) int64
        Output ``|N_R(i)|`` (diagnostics).

    Notes
    -----
    Tensor ``T_i = sum u_j n'_j n'_j^T`` with ``u_j = exp(-|p_j - p_i| / sigma_e)``,
    ``sigma_e = 2 r / 3`` and ``r`` the radius of ``N_R(i)`` (``u_j = 1`` when ``r = 0``).
    A neighbour whose normal is parallel to the connecting line, or that coincides with
    ``p_i``, votes its own normal. A zero vote sum counts as ``|nbar . e1| = 0`` (``s_i = 1``).

    Scratch: per thread, a stamp per point (``4 n`` bytes, written) and a queue and distance
    buffer of ``n`` entries each, of which only the first ``|N_R|`` entries are ever touched.
    Per-thread rather than per-chunk arrays, because marks that never need clearing make the
    membership test a single load, and arrays that are never reallocated inside the loop spare
    numba's reference counting (together 2.4x faster than a growable per-chunk hash set).
    """
    n = points.shape[0]
    radius2 = radius * radius
    stamps = np.full((n_slots, n), -1, indices.dtype)
    queues = np.empty((n_slots, n), indices.dtype)
    dists = np.empty((n_slots, n))
    for c in prange((n + CHUNK - 1) // CHUNK):
        slot = numba.get_thread_id()
        stamp = stamps[slot]
        queue = queues[slot]
        dist2 = dists[slot]
        tensor = np.empty((3, 3))
        w = np.empty(3)
        v = np.empty((3, 3))
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            count = grow_region(points, indptr, indices, i, radius2, n_vote, stamp, queue, dist2)
            out[i] = _vote(points, normals, i, queue, dist2, count, tensor, w, v, delta, alpha,
                           beta)
            region_size[i] = count
