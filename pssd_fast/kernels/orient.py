"""Consistent orientation of normals by propagation over the neighbour graph (Hoppe et al.,
"Surface reconstruction from unorganized points", 1992, Section 3.3)."""
import numpy as np

from .config import helper, serial_kernel


@helper
def _symmetric_lists(indptr, indices, limit):
    """The undirected graph of the first ``limit`` entries of every list (the point itself
    left out), in CSR form: each list holds its own entries in list order, then the points
    that list it, in increasing index order (a counting sort, so no sorting cost)."""
    n = indptr.shape[0] - 1
    degree = np.zeros(n + 1, np.int64)
    for i in range(n):
        stop = min(indptr[i + 1], indptr[i] + limit)
        for t in range(indptr[i], stop):
            j = indices[t]
            if j != i:
                degree[i + 1] += 1
                degree[j + 1] += 1
    start = np.cumsum(degree)
    fill = start[:-1].copy()
    adjacent = np.empty(start[n], indices.dtype)
    for reverse in (False, True):  # every list's own entries first, then who lists it
        for i in range(n):
            stop = min(indptr[i + 1], indptr[i] + limit)
            for t in range(indptr[i], stop):
                j = indices[t]
                if j != i:
                    at, other = (j, i) if reverse else (i, j)
                    adjacent[fill[at]] = other
                    fill[at] += 1
    return start, adjacent


@helper
def _before(key, a, b):
    """Heap order: by weight, then by point index (ties broken deterministically)."""
    return key[a] < key[b] or (key[a] == key[b] and a < b)


@helper
def _swap(heap, slot, x, y):
    a, b = heap[x], heap[y]
    heap[x], heap[y] = b, a
    slot[a], slot[b] = y, x


@helper
def _sift_up(heap, slot, key, pos):
    while pos > 0:
        up = (pos - 1) // 2
        if not _before(key, heap[pos], heap[up]):
            break
        _swap(heap, slot, pos, up)
        pos = up


@helper
def _pop(heap, slot, key, size):
    """Remove and return the heap's first point; ``size`` is the size before the call."""
    first = heap[0]
    last = size - 1
    _swap(heap, slot, 0, last)
    slot[first] = -1
    pos = 0
    while True:
        child = 2 * pos + 1
        if child >= last:
            break
        if child + 1 < last and _before(key, heap[child + 1], heap[child]):
            child += 1
        if not _before(key, heap[child], heap[pos]):
            break
        _swap(heap, slot, pos, child)
        pos = child
    return first


@serial_kernel
def propagate_orientation(indptr, indices, limit, normals, component):
    """Flip normals so that neighbours agree, along a minimum spanning tree of the graph.

    Prim's algorithm grows a tree over the undirected graph of the first ``limit`` entries of
    every list, each edge weighted by ``1 - |n_i . n_j|``, so that the sign travels between
    nearly parallel normals first and crosses creases where they turn least. A point reached
    from ``p`` is flipped when ``n_j . n_p < 0``. Each connected component starts at its
    lowest index, which keeps its normal; ``component`` receives the component number of each
    point (0, 1, ... in order of the lowest index).

    Parameters
    ----------
    indptr, indices : CSR neighbour graph (each list starting with the point itself)
    limit : int
        List entries used per point, the point itself included.
    normals : (n, 3) float64
        Unit normals, flipped in place.
    component : (n,) int64
        Output.

    Returns
    -------
    int
        Number of connected components.

    Notes
    -----
    Sequential by nature (each step depends on all earlier ones), hence a serial kernel. The
    heap holds each point once with its best edge so far (``n`` slots, not one per edge); ties
    in weight go to the lower point index, and between equal edges into one point to the lower
    parent index, so the tree depends on nothing but the inputs. Hoppe et al. weight the
    Riemannian graph (the EMST plus kNN edges); the kNN lists alone suffice here because every
    component is oriented separately afterwards.
    """
    n = normals.shape[0]
    start, adjacent = _symmetric_lists(indptr, indices, limit)
    heap = np.empty(n, np.int64)
    slot = np.full(n, -1, np.int64)  # position in the heap, -1 when not in it
    key = np.empty(n)
    parent = np.empty(n, np.int64)
    done = np.zeros(n, np.bool_)
    count = 0
    for seed in range(n):
        if done[seed]:
            continue
        heap[0], slot[seed], key[seed], parent[seed] = seed, 0, 0.0, seed
        size = 1
        while size > 0:
            j = _pop(heap, slot, key, size)
            size -= 1
            done[j] = True
            component[j] = count
            p = parent[j]
            if (normals[j, 0] * normals[p, 0] + normals[j, 1] * normals[p, 1]
                    + normals[j, 2] * normals[p, 2]) < 0.0:
                normals[j, 0] = -normals[j, 0]
                normals[j, 1] = -normals[j, 1]
                normals[j, 2] = -normals[j, 2]
            for t in range(start[j], start[j + 1]):
                m = adjacent[t]
                if done[m]:
                    continue
                w = 1.0 - abs(normals[j, 0] * normals[m, 0] + normals[j, 1] * normals[m, 1]
                              + normals[j, 2] * normals[m, 2])
                if slot[m] < 0:
                    heap[size], slot[m], key[m], parent[m] = m, size, w, j
                    size += 1
                elif w < key[m] or (w == key[m] and j < parent[m]):
                    key[m], parent[m] = w, j
                else:
                    continue
                _sift_up(heap, slot, key, slot[m])
        count += 1
    return count
