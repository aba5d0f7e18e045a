"""Kernels over the CSR neighbour graph itself: repairing raw kNN results, list lengths."""
from numba import prange

from .config import CHUNK, helper, parallel_kernel


@parallel_kernel
def put_self_first(indices, dists):
    """Make every row ``i`` of a distance-sorted kNN result start with ``i`` itself, in place.

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
    """
    n, k = indices.shape
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            if indices[i, 0] == i:
                continue
            pos = k - 1
            for t in range(1, k):
                if indices[i, t] == i:
                    pos = t
                    break
            for t in range(pos, 0, -1):
                indices[i, t] = indices[i, t - 1]
                dists[i, t] = dists[i, t - 1]
            indices[i, 0] = i
            dists[i, 0] = 0.0


@helper
def max_degree(indptr):
    """Length of the longest neighbour list (sizes the per-chunk scratch)."""
    longest = 0
    for i in range(indptr.shape[0] - 1):
        longest = max(longest, indptr[i + 1] - indptr[i])
    return longest
