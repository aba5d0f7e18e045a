"""Kernels over the CSR neighbour graph itself: repairing raw kNN results, list lengths."""
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
