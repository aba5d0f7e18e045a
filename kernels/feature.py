"""Region-grown neighbourhoods and the normal voting tensor (ALGORITHM.md, step 2; Section 3)."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .linalg import sym3_eigh

# Initial capacity of the per-chunk region scratch; it doubles when a region outgrows it.
INITIAL_CAPACITY = 1024
# Below this squared length the tangential part of a neighbour's normal is taken as zero: the
# normal points along the connecting line and the vote cannot rotate it.
TINY = 1e-30


@helper
def _insert(table, j):
    """Insert ``j`` into an open-addressing set; return its slot, or -1 if already present."""
    mask = table.shape[0] - 1
    s = (j * 2654435761) & mask
    while True:
        e = table[s]
        if e == j:
            return -1
        if e < 0:
            table[s] = j
            return s
        s = (s + 1) & mask


@helper
def _grow(queue, slots, count):
    """Double the region scratch, re-inserting the ``count`` members already queued."""
    cap = 2 * queue.shape[0]
    new_queue = np.empty(cap, np.int64)
    new_slots = np.empty(cap, np.int64)
    table = np.full(2 * cap, -1, np.int64)
    for t in range(count):
        new_queue[t] = queue[t]
        new_slots[t] = _insert(table, queue[t])
    return new_queue, new_slots, table


@helper
def grow_region(points, indptr, indices, i, radius2, n_vote, queue, slots, table):
    """Breadth-first region growing of ``N_R(i)``.

    Starting from ``i``, each member adds those of the first ``n_vote`` entries of its own
    neighbour list that lie within ``sqrt(radius2)`` of ``p_i`` and are not members yet.
    Members are left in ``queue[:count]`` in discovery order; the set ``table`` records them and
    must be cleared by the caller (``table[slots[:count]] = -1``). Arrays are replaced by larger
    ones when a region outgrows them, so they are returned.
    """
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    queue[0] = i
    slots[0] = _insert(table, i)
    count = 1
    head = 0
    while head < count:
        j = queue[head]
        head += 1
        start = indptr[j]
        stop = min(indptr[j + 1], start + n_vote)
        for t in range(start, stop):
            cand = indices[t]
            dx = points[cand, 0] - px
            dy = points[cand, 1] - py
            dz = points[cand, 2] - pz
            if dx * dx + dy * dy + dz * dz > radius2:
                continue
            s = _insert(table, cand)
            if s < 0:
                continue
            if count == queue.shape[0]:
                queue, slots, table = _grow(queue, slots, count)
                s = _insert(table, cand)
            queue[count] = cand
            slots[count] = s
            count += 1
    return count, queue, slots, table


@helper
def _vote(points, normals, i, queue, count, tensor, w, v, delta, alpha, beta):
    """Feature intensity of point ``i`` from the voted normals of its region ``queue[:count]``."""
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    nix, niy, niz = normals[i, 0], normals[i, 1], normals[i, 2]
    r2 = 0.0
    for t in range(count):
        j = queue[t]
        dx = points[j, 0] - px
        dy = points[j, 1] - py
        dz = points[j, 2] - pz
        r2 = max(r2, dx * dx + dy * dy + dz * dz)
    sigma = 2.0 * math.sqrt(r2) / 3.0
    inv_sigma = 1.0 / sigma if sigma > 0.0 else 0.0

    t00 = t01 = t02 = t11 = t12 = t22 = 0.0
    bx = by = bz = 0.0
    for t in range(count):
        j = queue[t]
        nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
        if nx * nix + ny * niy + nz * niz < 0.0:
            nx, ny, nz = -nx, -ny, -nz
        vx = px - points[j, 0]
        vy = py - points[j, 1]
        vz = pz - points[j, 2]
        vv = vx * vx + vy * vy + vz * vz
        if vv > 0.0:
            # w = normalize((v x n) x v): the part of n perpendicular to v; n' reflects n's
            # component along v (Page et al.'s vote of n_j at p_i along the connecting arc).
            vn = (vx * nx + vy * ny + vz * nz) / vv
            wx = nx - vn * vx
            wy = ny - vn * vy
            wz = nz - vn * vz
            ww = wx * wx + wy * wy + wz * wz
            if ww > TINY:
                inv = 1.0 / math.sqrt(ww)
                wx *= inv
                wy *= inv
                wz *= inv
                nw = 2.0 * (nx * wx + ny * wy + nz * wz)
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
    tensor[0, 0] = t00
    tensor[0, 1] = t01
    tensor[0, 2] = t02
    tensor[1, 0] = t01
    tensor[1, 1] = t11
    tensor[1, 2] = t12
    tensor[2, 0] = t02
    tensor[2, 1] = t12
    tensor[2, 2] = t22
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
                      out, region_size):
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
    """
    n = points.shape[0]
    radius2 = radius * radius
    for c in prange((n + CHUNK - 1) // CHUNK):
        queue = np.empty(INITIAL_CAPACITY, np.int64)
        slots = np.empty(INITIAL_CAPACITY, np.int64)
        table = np.full(2 * INITIAL_CAPACITY, -1, np.int64)
        tensor = np.empty((3, 3))
        w = np.empty(3)
        v = np.empty((3, 3))
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            count, queue, slots, table = grow_region(
                points, indptr, indices, i, radius2, n_vote, queue, slots, table)
            out[i] = _vote(points, normals, i, queue, count, tensor, w, v, delta, alpha, beta)
            region_size[i] = count
            for t in range(count):
                table[slots[t]] = -1
