"""Region-grown neighbourhoods and the normal voting tensor (docs/ALGORITHM.md, step 2; paper
Section 3)."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel
from .linalg import set_sym3, sym3_eigh

# Below this squared length the tangential part of a neighbour's normal is taken as zero: the
# normal points along the connecting line and the vote cannot rotate it.
TINY = 1e-30
# Regions are grown for this many consecutive points at once, one bit of a uint64 each.
BLOCK = 64
# Node tables of a chunk start with this many slots and double when a block needs more.
NODES = 4096
# exp(-x) on [0, 1.5] (the range of |p_j - p_i| / sigma_e) as e^-0.75 exp(0.75 - x), the second
# factor by its Taylor polynomial of degree 15 (relative error below 4e-15): a loop calling
# math.exp does not vectorise.
_E075 = math.exp(-0.75)
C0, C1, C2, C3, C4, C5, C6, C7, C8, C9, C10, C11, C12, C13, C14, C15 = (
    1.0 / math.factorial(d) for d in range(16))


@helper
def _exp_neg(x):
    """``exp(-x)`` for ``x`` in [0, 1.5] (see ``C0``)."""
    y = 0.75 - x
    s = C15 * y + C14
    s = s * y + C13
    s = s * y + C12
    s = s * y + C11
    s = s * y + C10
    s = s * y + C9
    s = s * y + C8
    s = s * y + C7
    s = s * y + C6
    s = s * y + C5
    s = s * y + C4
    s = s * y + C3
    s = s * y + C2
    s = s * y + C1
    s = s * y + C0
    return _E075 * s


@helper
def _ball_mask(points, c, sources, m, radius2):
    """Bit ``b`` set where ``p_c`` lies within ``R`` of source ``b``, whose coordinates are
    ``sources[:, b]`` (one row per axis, so that the loop vectorises)."""
    cx, cy, cz = points[c, 0], points[c, 1], points[c, 2]
    mask = np.uint64(0)
    for b in range(m):
        dx = cx - sources[0, b]
        dy = cy - sources[1, b]
        dz = cz - sources[2, b]
        inside = np.uint64(dx * dx + dy * dy + dz * dz <= radius2)
        mask |= inside << np.uint64(b)
    return mask


@helper
def _find(table, c):
    """Position of point ``c`` in the open-addressing table ``table`` (capacity a power of two,
    -1 marks a free entry), or of the free entry where it belongs."""
    mask = table.shape[0] - 1
    h = (np.int64(c) * np.int64(2654435761)) & mask
    while table[h] != c and table[h] >= 0:
        h = (h + 1) & mask
    return h


@helper
def _add_node(points, c, h, sources, m, radius2, table, slot_at, nodes, ball, reach, queued,
              count):
    """Give point ``c`` (free table entry ``h``) the next free slot ``count`` of the node
    table."""
    table[h] = c
    slot_at[h] = count
    nodes[count] = c
    ball[count] = _ball_mask(points, c, sources, m, radius2)
    reach[count] = np.uint64(0)
    queued[count] = False


@helper
def grow_block(points, indptr, indices, start, stop, radius2, n_vote, sources, table, slot_at,
               nodes, ball, reach, queued, work, listed, n_listed):
    """Grow ``N_R(i)`` for each ``i`` in ``start..stop-1`` (at most ``BLOCK``) together.

    Returns ``count``, the number of points examined; ``nodes[:count]`` are their indices and
    bit ``b`` of ``reach[t]`` is set exactly when ``nodes[t]`` belongs to ``N_R(start + b)``.
    Returns -1 when the block needs more than ``nodes.shape[0]`` nodes: the caller grows the
    tables and calls again.

    ``N_R(i)`` is the set of points reachable from ``i`` along the first ``n_vote`` entries of
    each member's list without leaving the ball of radius ``R`` around ``p_i``
    (docs/ALGORITHM.md step 2). Instead of one breadth-first search per point, a work list
    propagates bit masks: a node passes the bits it has reached to each listed neighbour whose
    ball mask (the sources within ``R`` of it) contains them, and is queued again when it gains
    bits. Neighbouring points share most of their regions, so each node is examined about once
    per block instead of once per point.

    Scratch, all sized by the block's nodes, not by the cloud: ``sources`` (3, ``BLOCK``)
    receives the block's coordinates; ``table`` and ``slot_at`` (at least twice the node
    capacity, a power of two) map points to node slots; ``nodes``, ``ball``, ``reach``,
    ``queued`` and the ring buffer ``work`` hold one entry per node; ``listed`` (nodes,
    ``n_vote - 1``) and ``n_listed`` the slots of each node's listed neighbours once it has
    been examined, so that a node examined again (about 0.6 times a node) looks none up.
    """
    m = stop - start
    for b in range(m):
        for a in range(3):
            sources[a, b] = points[start + b, a]
    table[:] = -1
    capacity = work.shape[0]
    count = 0
    # Ring buffer: a node is queued at most once at a time, so ``pending <= capacity``.
    head = 0
    tail = 0
    pending = 0
    for b in range(m):
        i = start + b
        h = _find(table, i)
        if table[h] < 0:
            if count == capacity:
                return -1
            _add_node(points, i, h, sources, m, radius2, table, slot_at, nodes, ball, reach,
                      queued, count)
            n_listed[count] = -1
            count += 1
        s = slot_at[h]
        reach[s] |= np.uint64(1) << np.uint64(b)
        if not queued[s]:
            queued[s] = True
            work[tail] = s
            tail = tail + 1 if tail + 1 < capacity else 0
            pending += 1
    while pending:
        s = work[head]
        head = head + 1 if head + 1 < capacity else 0
        pending -= 1
        queued[s] = False
        bits = reach[s]
        if n_listed[s] < 0:
            # First examined: its listed neighbours found (new ones added, in list order).
            j = nodes[s]
            # The list's first entry is j itself, which has its own bits already.
            first = indptr[j] + 1
            e = 0
            for t in range(first, min(indptr[j + 1], first + n_vote - 1)):
                c = indices[t]
                h = _find(table, c)
                if table[h] < 0:
                    if count == capacity:
                        return -1
                    _add_node(points, c, h, sources, m, radius2, table, slot_at, nodes, ball,
                              reach, queued, count)
                    n_listed[count] = -1
                    count += 1
                listed[s, e] = slot_at[h]
                e += 1
            n_listed[s] = e
        for e in range(n_listed[s]):
            cs = listed[s, e]
            add = bits & ball[cs] & ~reach[cs]
            reach[cs] |= add
            # Queued where it gained bits and is not queued yet, without a branch: the store
            # at the tail is harmless where not, since that slot is free (node s is out of
            # the queue, so fewer than the capacity are in it).
            join = (add != np.uint64(0)) & (not queued[cs])
            queued[cs] |= join
            work[tail] = cs
            tail += np.int64(join)
            tail = tail if tail < capacity else 0
            pending += np.int64(join)
    return count


@helper
def _classify(tensor, w, v, bx, by, bz, delta, alpha, beta):
    """Eq. (3): feature intensity from the vote tensor (in ``tensor``) and the vote sum."""
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


@helper
def _vote(points, normals, i, b, count, reach, gathered, members, soa, tensor, w, v, delta,
          alpha, beta):
    """Feature intensity of point ``i`` = source ``b`` of the block, and its region size.

    Row ``t < count`` of ``gathered`` holds the position (columns 0-2) and normal (3-5) of the
    block's node ``t``, padded to 8 values: one cache line per member, which the vote reads in
    a data-dependent order (25% faster than one row per coordinate). The region is the nodes
    with bit ``b`` of ``reach`` set; their slots are first listed in ``members`` by a loop
    without branches (a store to every position, kept or not). Their offsets and normals are
    then copied into the rows of ``soa``, where each member's vote and weight are computed by a
    loop without sums or branches, which LLVM vectorises (at 1,000,000 points the feature stage
    took 2.2 times as long with the vote and the sums in one loop); the sums follow in a loop
    of their own, in the members' order, so the bits are those of one loop.
    """
    shift = np.uint64(b)
    one = np.uint64(1)
    size = 0
    for t in range(count):
        members[size] = t
        size += np.int64((reach[t] >> shift) & one)
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    r2 = 0.0
    for s in range(size):
        t = members[s]
        dx = px - gathered[t, 0]
        dy = py - gathered[t, 1]
        dz = pz - gathered[t, 2]
        soa[0, s] = dx
        soa[1, s] = dy
        soa[2, s] = dz
        soa[3, s] = gathered[t, 3]
        soa[4, s] = gathered[t, 4]
        soa[5, s] = gathered[t, 5]
        r2 = max(r2, dx * dx + dy * dy + dz * dz)
    sigma = 2.0 * math.sqrt(r2) / 3.0
    inv_sigma = 1.0 / sigma if sigma > 0.0 else 0.0
    nix, niy, niz = normals[i, 0], normals[i, 1], normals[i, 2]
    for s in range(size):
        # w = (v x n) x v / |v|^2 is the part of n perpendicular to v; Page et al.'s vote
        # n' = 2 (n . w^) w^ - n, with w^ = w / |w|, is 2 w - n for a unit n (then n . w = |w|^2):
        # n with its component along v reflected. v = 0 (p_i itself or a twin) or w = 0 (n along
        # v): n votes itself. Selects, not branches, so that the loop vectorises.
        vx = soa[0, s]
        vy = soa[1, s]
        vz = soa[2, s]
        nx = soa[3, s]
        ny = soa[4, s]
        nz = soa[5, s]
        flip = nx * nix + ny * niy + nz * niz < 0.0
        nx = -nx if flip else nx
        ny = -ny if flip else ny
        nz = -nz if flip else nz
        vv = vx * vx + vy * vy + vz * vz
        vn = (vx * nx + vy * ny + vz * nz) / (vv if vv > 0.0 else 1.0)
        vn = vn if vv > 0.0 else 0.0
        wx = nx - vn * vx
        wy = ny - vn * vy
        wz = nz - vn * vz
        ww = wx * wx + wy * wy + wz * wz
        turn = vv > 0.0 and ww > TINY
        soa[3, s] = 2.0 * wx - nx if turn else nx
        soa[4, s] = 2.0 * wy - ny if turn else ny
        soa[5, s] = 2.0 * wz - nz if turn else nz
        soa[6, s] = _exp_neg(math.sqrt(vv) * inv_sigma)
    t00 = t01 = t02 = t11 = t12 = t22 = 0.0
    bx = by = bz = 0.0
    for s in range(size):
        nx, ny, nz, u = soa[3, s], soa[4, s], soa[5, s], soa[6, s]
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
    return _classify(tensor, w, v, bx, by, bz, delta, alpha, beta), size


@helper
def _node_tables(capacity, index_dtype, n_vote):
    """Scratch of :func:`grow_block` and :func:`_vote` for ``capacity`` nodes."""
    return (np.empty(2 * capacity, index_dtype), np.empty(2 * capacity, np.int64),
            np.empty(capacity, index_dtype), np.empty(capacity, np.uint64),
            np.empty(capacity, np.uint64), np.empty(capacity, np.bool_),
            np.empty(capacity, np.int64), np.empty((capacity, 8)),
            np.empty(capacity, np.int64), np.empty((7, capacity)),
            np.empty((capacity, max(n_vote - 1, 1)), np.int32), np.empty(capacity, np.int32))


@helper
def _feature_chunk(points, normals, indptr, indices, radius2, n_vote, delta, alpha, beta, lo, hi,
                   out, region_size):
    """:func:`feature_intensity` for the points ``lo..hi-1``, block by block, with node tables
    of its own that grow when a block needs more.

    A function of its own, not the body of the ``prange`` loop: written inline, a body that
    reallocates its scratch gave wrong results for every block after the first reallocation
    under numba's parfor transformations (``tests/test_stages.py`` covers the growth).
    """
    capacity = NODES
    table, slot_at, nodes, ball, reach, queued, work, gathered, members, soa, listed, \
        n_listed = _node_tables(capacity, indices.dtype, n_vote)
    sources = np.empty((3, BLOCK))
    tensor = np.empty((3, 3))
    w = np.empty(3)
    v = np.empty((3, 3))
    for start in range(lo, hi, BLOCK):
        stop = min(hi, start + BLOCK)
        count = grow_block(points, indptr, indices, start, stop, radius2, n_vote, sources,
                           table, slot_at, nodes, ball, reach, queued, work, listed, n_listed)
        while count < 0:
            capacity *= 2
            table, slot_at, nodes, ball, reach, queued, work, gathered, members, soa, listed, \
                n_listed = _node_tables(capacity, indices.dtype, n_vote)
            count = grow_block(points, indptr, indices, start, stop, radius2, n_vote, sources,
                               table, slot_at, nodes, ball, reach, queued, work, listed,
                               n_listed)
        for t in range(count):
            j = nodes[t]
            for a in range(3):
                gathered[t, a] = points[j, a]
                gathered[t, 3 + a] = normals[j, a]
        for i in range(start, stop):
            out[i], region_size[i] = _vote(points, normals, i, i - start, count, reach,
                                           gathered, members, soa, tensor, w, v, delta,
                                           alpha, beta)


@parallel_kernel
def feature_intensity(points, normals, indptr, indices, radius, n_vote, delta, alpha, beta, out,
                      region_size):
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

    Regions are grown for blocks of ``BLOCK`` consecutive points at once (see
    :func:`grow_block`); in Morton order these are close in space and share most members.
    Scratch is per chunk of points and sized by a block's nodes (``NODES`` slots at first,
    doubled when a block needs more): about 210 bytes a node, whatever the cloud's size and
    the thread count.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        _feature_chunk(points, normals, indptr, indices, radius * radius, n_vote, delta, alpha,
                       beta, c * CHUNK, min(n, (c + 1) * CHUNK), out, region_size)
