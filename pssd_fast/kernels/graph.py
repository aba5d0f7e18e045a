"""Kernels over the CSR neighbour graph itself: repairing raw kNN results, re-sorting lists
after the points moved, list lengths."""
import math

import numpy as np
from numba import prange

from .config import CHUNK, helper, parallel_kernel


@parallel_kernel
def put_self_first(indices, dists, first):
    """Make every row ``r`` of a distance-sorted kNN result start with its own point
    ``i = first + r``, in place.

    With exact duplicates the query may list a twin before the point itself (a tie at distance
    0), or, with more than ``k`` twins, not list it at all. The point is moved to the front
    (shifting the tied entries right, which keeps the rows sorted); if it is missing, the last
    entry is dropped to make room.

    Parameters
    ----------
    indices : (n, k) integer
        Neighbour indices of each row, sorted by distance.
    dists : (n, k) float64
        Matching distances.
    first : int
        Index of the point of row 0 (the rows are a chunk of the whole query).
    """
    n, k = indices.shape
    for c in prange((n + CHUNK - 1) // CHUNK):
        for r in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            i = first + r
            if indices[r, 0] == i:
                continue
            pos = k - 1
            for t in range(1, k):
                if indices[r, t] == i:
                    pos = t
                    break
            for t in range(pos, 0, -1):
                indices[r, t] = indices[r, t - 1]
                dists[r, t] = dists[r, t - 1]
            indices[r, 0] = i
            dists[r, 0] = 0.0


@helper
def max_degree(indptr):
    """Length of the longest neighbour list (sizes the per-chunk scratch)."""
    longest = 0
    for i in range(indptr.shape[0] - 1):
        longest = max(longest, indptr[i + 1] - indptr[i])
    return longest


@parallel_kernel
def refresh_lists(points, indptr, indices, radius, nearest):
    """Re-sort every list by the current distances, in place, after the points have moved.

    Each list keeps its members (a later iteration reuses the first iteration's neighbours)
    and is put back in order of distance by a stable insertion sort, so the point itself stays
    first and ties keep their order. ``radius`` and ``nearest`` receive the distances to the
    last and the second member: the list radius and the nearest other point.
    """
    n = indptr.shape[0] - 1
    longest = max_degree(indptr)
    for c in prange((n + CHUNK - 1) // CHUNK):
        dist = np.empty(longest)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            start = indptr[i]
            count = indptr[i + 1] - start
            for t in range(count):
                j = indices[start + t]
                dx = points[j, 0] - points[i, 0]
                dy = points[j, 1] - points[i, 1]
                dz = points[j, 2] - points[i, 2]
                d = math.sqrt(dx * dx + dy * dy + dz * dz)
                s = t
                while s > 0 and dist[s - 1] > d:
                    dist[s] = dist[s - 1]
                    indices[start + s] = indices[start + s - 1]
                    s -= 1
                dist[s] = d
                indices[start + s] = j
            radius[i] = dist[count - 1]
            nearest[i] = dist[1] if count > 1 else 0.0


@parallel_kernel
def pack_rows(rows, lengths, starts, out):
    """The first ``lengths[r]`` entries of each row ``r`` of ``rows`` (m, k) into
    ``out[starts[r]:starts[r] + lengths[r]]``: ragged lists packed end to end (numpy's boolean
    gather of the same entries makes and reads a mask of every entry)."""
    m = rows.shape[0]
    for c in prange((m + CHUNK - 1) // CHUNK):
        for r in range(c * CHUNK, min(m, (c + 1) * CHUNK)):
            at = starts[r]
            for t in range(lengths[r]):
                out[at + t] = rows[r, t]


@parallel_kernel
def keep_nearest(dists, found, missing, ids, kept, kept_dists, lengths):
    """The nearest entries of each distance-sorted row of a ``k + 1``-nearest query: those
    nearer than the row's last entry, ordered by distance, then index.

    Which of several points at one distance a tree returns depends on the tree; the set of the
    points nearer than the ``k + 1``-th distance does not (the distances are exact). So a tie at
    the cut keeps none of the tied points, and the rows are the same whichever points the tree
    held beyond them (a tile and its halo, or the whole cloud). Entries the query did not find
    (beyond its bound) are infinite.

    Parameters
    ----------
    dists, found : (m, k + 1) float64, int64
        The query's distances and indices, each row sorted by distance.
    missing : int
        The index written where fewer than ``k`` entries are kept.
    ids : (n,) int64 or (0,)
        The order of tied entries: by ``ids[j]`` (a tile's points keep their place in the whole
        cloud), or with no entries by ``j``.
    kept, kept_dists : (m, k) int64, float64
        Output: the kept entries first, then ``missing`` and infinity.
    lengths : (m,) int64
        Output: how many entries each row kept.
    """
    m, q = dists.shape
    for c in prange((m + CHUNK - 1) // CHUNK):
        for r in range(c * CHUNK, min(m, (c + 1) * CHUNK)):
            cut = dists[r, q - 1]
            count = 0
            for t in range(q - 1):
                d = dists[r, t]
                if not d < cut:
                    break
                j = found[r, t]
                key = ids[j] if ids.shape[0] > 0 else j
                s = count
                while s > 0 and (kept_dists[r, s - 1] > d or (
                        kept_dists[r, s - 1] == d
                        and (ids[kept[r, s - 1]] if ids.shape[0] > 0 else kept[r, s - 1]) > key)):
                    kept_dists[r, s] = kept_dists[r, s - 1]
                    kept[r, s] = kept[r, s - 1]
                    s -= 1
                kept_dists[r, s] = d
                kept[r, s] = j
                count += 1
            for t in range(count, q - 1):
                kept[r, t] = missing
                kept_dists[r, t] = np.inf
            lengths[r] = count
