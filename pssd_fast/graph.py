"""The k-nearest-neighbour graph, stored as CSR arrays, built with pykdtree."""
from typing import NamedTuple

import numpy as np

from . import interop
from ._threads import kdtree, threads
from ._validation import as_points, check_k
from .kernels.boxes import inside_any, near_any
from .kernels.graph import keep_nearest, pack_rows, put_self_first, refresh_lists
from .kernels.knn import grid_knn
from .kernels.order import cell_coordinates, interleave, morton_codes, stable_argsort

MORTON_BITS = 21  # per axis: 3 * 21 = 63 bits fit an unsigned 64-bit code


class NeighborGraph(NamedTuple):
    """A neighbour graph in CSR form: the list of point ``i`` is ``indices[indptr[i]:indptr[i+1]]``.

    Attributes
    ----------
    indptr : (n + 1,) int64
        Start of each point's list in ``indices``.
    indices : (nnz,) int32 (int64 beyond 2**31 points)
        Neighbour indices; each list is sorted by distance and starts with the point itself.
    distances : (nnz,) float64
        Euclidean distance from the point to each listed neighbour.
    """

    indptr: np.ndarray
    indices: np.ndarray
    distances: np.ndarray

    @property
    def n_points(self):
        """Number of points (rows)."""
        return self.indptr.shape[0] - 1

    def list_radius(self):
        """``r_i``: distance from each point to the farthest member of its list, shape (n,)."""
        return self.distances[self.indptr[1:] - 1]

    def nearest_distance(self):
        """Distance from each point to its nearest *other* listed point, shape (n,)."""
        return self.distances[self.indptr[:-1] + 1]


def bounds(points):
    """Lowest and highest coordinate on each axis of an ``(n, 3)`` array.

    Column by column: numpy's ``min(axis=0)`` over three interleaved columns is about twenty
    times slower (0.66 ms against 0.03 ms at 30,000 points).
    """
    low = np.array([points[:, axis].min() for axis in range(3)])
    high = np.array([points[:, axis].max() for axis in range(3)])
    return low, high


def morton_order(points):
    """Permutation that sorts points along a Z-order (Morton) space-filling curve.

    Parameters
    ----------
    points : (n, 3) array_like
        Finite coordinates, at least one point (checked: a ValueError or TypeError names
        what is wrong).

    Returns
    -------
    (n,) int64
        ``points[order]`` visits the cloud along the curve, so that neighbours in space are
        mostly neighbours in memory. Ties keep the input order (stable sort): deterministic.
    """
    return curve_order(as_points(interop.coordinates(points))[0])


def curve_order(points):
    """:func:`morton_order` of valid float64 ``points``."""
    return code_order(morton_cells(points))


#: From this many codes on, :func:`code_order` sorts by radix (numpy's stable sort of uint64
#: merges runs: 0.20 s against 0.075 s for 2,000,000 codes in input order on 2 cores); below,
#: the radix kernel's first compile would outweigh what it saves.
RADIX_POINTS = 100_000


def code_order(codes):
    """``np.argsort(codes, kind="stable")`` of uint64 codes, the same permutation by a radix
    sort (:func:`pssd_fast.kernels.order.stable_argsort`) from :data:`RADIX_POINTS` codes
    on."""
    if codes.shape[0] < RADIX_POINTS:
        return np.argsort(codes, kind="stable")
    order = np.empty(codes.shape[0], np.int64)
    stable_argsort(np.ascontiguousarray(codes, dtype=np.uint64), order)
    return order


def morton_cells(points):
    """The Morton code of each point's cell in the grid of :func:`morton_order`: ``2**21 - 1``
    cells along the bounding box's longest side, on every axis."""
    low, high = bounds(points)
    extent = float((high - low).max())
    scale = (2**MORTON_BITS - 1) / extent if extent > 0.0 else 0.0
    return grid_codes(points, low, scale)


def grid_codes(points, low, scale):
    """The Morton code of each point's cell in the grid of cells of side ``1 / scale`` from
    ``low`` (at most ``2**21 - 1`` cells an axis)."""
    code = np.empty(points.shape[0], np.uint64)
    morton_codes(np.ascontiguousarray(points, dtype=np.float64), low, scale, code)
    return code


def cell_keys(points, low, edge, shift=None):
    """What orders the grid cells of edge ``edge`` from ``low`` along a Morton curve, however
    many there are: each point's cell coordinates ``(n, 3)`` int64, and the Morton code of
    those coordinates shifted right by ``shift`` bits (by default as few as leave 21 an axis
    on these points; a cloud longer than ``2**21`` cells is ordered by the curve of coarser
    cells, then by the coordinates). Sorting by the code, then the coordinates, groups each
    cell's points and keeps their order (:func:`numpy.lexsort`)."""
    n = points.shape[0]
    cells = np.empty((n, 3), np.int64)
    cell_coordinates(np.ascontiguousarray(points, dtype=np.float64), low, 1.0 / edge, cells)
    if shift is None:
        shift = max(0, int(cells.max(initial=0)).bit_length() - MORTON_BITS)
    code = np.empty(n, np.uint64)
    interleave(cells, shift, code)
    return code, cells


def inside_boxes(points, boxes):
    """The mask of ``points`` inside any of ``boxes`` ``(p, 2, 3)`` (low and high corners),
    faces included."""
    inside = np.empty(points.shape[0], np.bool_)
    inside_any(np.ascontiguousarray(points, dtype=np.float64),
               np.ascontiguousarray(boxes, dtype=np.float64), inside)
    return inside


#: Grids of the centres of :func:`near_centres` up to this many cells get a table of every
#: cell (4 bytes each, 16 MB at most): one lookup a point where larger ones search.
DENSE_CELLS = 2**22


def near_centres(points, centres, radius):
    """The mask of ``points`` within ``radius`` of any of ``centres`` (distances at most
    ``radius``): the centres hashed into a grid of cells at least ``radius`` wide, and each
    point tested against those of its cell and its neighbours."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    out = np.zeros(points.shape[0], np.bool_)
    if not centres.shape[0] or not points.shape[0]:
        return out
    centres = np.ascontiguousarray(centres, dtype=np.float64)
    # A hair wider than the radius, so that rounding never puts a centre two cells away;
    # at most 2^20 cells an axis, so that the keys fit.
    span = float((centres.max(axis=0) - centres.min(axis=0)).max())
    cell = max(radius * (1.0 + 1e-6), span / 2.0 ** 20) or 1.0
    inv_cell = 1.0 / cell
    # Empty layers of cells around the centres', where their neighbours are (two below, so
    # that rounding never puts a centre in the first).
    low = centres.min(axis=0) - 2.0 * cell
    at = np.floor((centres - low) * inv_cell).astype(np.int64)
    dims = at.max(axis=0) + 3

    def keyed(cells):
        return (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]

    key = keyed(at)
    order = np.argsort(key, kind="stable")
    keys, starts = np.unique(key[order], return_index=True)
    occupied = np.stack([keys // (dims[1] * dims[2]), keys // dims[2] % dims[1],
                         keys % dims[2]], axis=1)
    steps = np.stack(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    reached = np.unique(keyed((occupied[:, None, :] + steps[None]).reshape(-1, 3)))
    dense = np.empty(0, np.int32)
    if float(np.prod(dims.astype(np.float64))) <= DENSE_CELLS:
        dense = np.full(int(np.prod(dims)), -1, np.int32)
        dense[reached] = -2
        dense[keys] = np.arange(keys.shape[0], dtype=np.int32)
    near_any(points, centres[order], low, inv_cell, dims, keys,
             np.append(starts, centres.shape[0]).astype(np.int64), reached, dense,
             radius * radius, out)
    return out


def cell_order(code, cells):
    """The order that groups the points by cell (:func:`cell_keys`), stably, and where each
    cell starts in it (with the end)."""
    order = code_order(code)
    keys = cells[order]
    change = np.concatenate(([True], (keys[1:] != keys[:-1]).any(axis=1)))
    # Where each code is one cell (up to 2**21 cells an axis) the stable sort by code is the
    # sort by code, then coordinates; runs of a coarser code hold several cells, which the
    # coordinates order.
    ordered = code[order]
    if (change[1:] & (ordered[1:] == ordered[:-1])).any():
        order = np.lexsort((cells[:, 2], cells[:, 1], cells[:, 0], code))
        keys = cells[order]
        change = np.concatenate(([True], (keys[1:] != keys[:-1]).any(axis=1)))
    starts = np.concatenate((np.flatnonzero(change), [order.shape[0]])).astype(np.int64)
    return order, starts


class ListScales(NamedTuple):
    """The part of a kNN graph :func:`pssd_fast.denoise` keeps: the lists and two distances
    per point instead of one per list entry (``8 k`` fewer bytes per point).

    Attributes
    ----------
    indptr, indices : as in :class:`NeighborGraph`
    radius : (n,) float64
        Distance to the farthest member of each list (:meth:`NeighborGraph.list_radius`).
    nearest : (n,) float64
        Distance to the nearest other member (:meth:`NeighborGraph.nearest_distance`).
    """

    indptr: np.ndarray
    indices: np.ndarray
    radius: np.ndarray
    nearest: np.ndarray

    def list_radius(self):
        """``r_i``, shape (n,)."""
        return self.radius

    def nearest_distance(self):
        """Distance to the nearest other listed point, shape (n,)."""
        return self.nearest


#: List entries per pykdtree query call (points per call: this over k): bounds the query's own
#: output (12 bytes per entry, float64 distances and uint32 indices) to 24 MB whatever k is,
#: while keeping each call long enough for its OpenMP threads.
QUERY_ENTRIES = 2**21


_NO_IDS = np.empty(0, np.int64)

#: From this list length on, lists come from the grid query (:mod:`pssd_fast.kernels.knn`)
#: instead of pykdtree, whose cost grows about as ``k^2`` (docs/DECISIONS.md, "Long lists").
GRID_K = 128
#: From this query length on (``k + 1``), bounded lists of the data's own points
#: (:func:`nearest_within`) come from the grid query: the same bits as from pykdtree, whose
#: ties :func:`pssd_fast.kernels.graph.keep_nearest` orders, and faster from about 40
#: (docs/DECISIONS.md, "Long lists").
BOUNDED_GRID_K = 48
#: ... and from this many points on, or from ``GRID_K`` entries on at any size: below both,
#: the grid saves a fraction of a second a run (the demo at 60,000 points, lists of 83 means:
#: 0.06 s of 1.26), less than its kernel's first compile costs (about 11 s); lists of
#: ``GRID_K`` take pykdtree long enough (the default at 30,000-60,000 points and 1% noise:
#: 13-15% of its run) to pay for it.
BOUNDED_GRID_POINTS = 100_000
#: The sample points whose lists set the grid's cell in a bounded query (:func:`_grid_cell`):
#: its cost, not its lists, depends on them.
GRID_LOOKED = 1000


def knn_graph(points, k, keep_distances=True):
    """kNN graph of already validated, C-contiguous float64 points, in their own order.

    Returns a :class:`NeighborGraph`, or with ``keep_distances=False`` a :class:`ListScales`.
    The query runs in chunks of ``QUERY_ENTRIES // k`` points, written straight into the final
    index array, so the peak memory is the graph itself. Lists of ``GRID_K`` or more entries
    come from the grid query, shorter ones from pykdtree; both are exact.
    """
    n = points.shape[0]
    query = _grid_query(points, k) if k >= GRID_K else _tree_query(points, k)
    indices = np.empty((n, k), np.int32 if n < 2**31 else np.int64)
    if keep_distances:
        dists = np.empty((n, k))
    else:
        radius = np.empty(n)
        nearest = np.empty(n)
    chunk = max(1, QUERY_ENTRIES // k)
    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        rows = indices[start:stop]
        chunk_dists = query(start, stop, rows)
        put_self_first(rows, chunk_dists, start)
        if keep_distances:
            dists[start:stop] = chunk_dists
        else:
            radius[start:stop] = chunk_dists[:, -1]
            nearest[start:stop] = chunk_dists[:, 1]
    indptr = np.arange(0, n * k + 1, k, dtype=np.int64)
    if keep_distances:
        return NeighborGraph(indptr, indices.reshape(-1), dists.reshape(-1))
    return ListScales(indptr, indices.reshape(-1), radius, nearest)


def nearest_within(data, queries, k, bound, ids=None):
    """The ``k`` nearest of ``data`` within distance ``bound`` of each of ``queries``: ``(rows,
    distances, lengths)``, ``(q, k)`` arrays of indices (``len(data)`` where fewer were kept)
    and distances, by distance then index, and how many each kept.

    A row holds the points nearer than the ``k + 1``-th nearest (none of several tied at that
    distance; :func:`pssd_fast.kernels.graph.keep_nearest`) and within ``bound``: it depends
    only on the data within ``bound``, whichever others the query saw, so that a tile with a
    halo ``bound`` wide gets the whole cloud's rows. Tied points are ordered by index, or by
    ``ids`` (each data point's place in the whole cloud) where given. The query runs in chunks
    of ``QUERY_ENTRIES // (k + 1)`` rows.
    """
    m = queries.shape[0]
    rows = np.empty((m, k), np.int64)
    distances = np.empty((m, k))
    lengths = np.empty(m, np.int64)
    for start, stop, found, dists, kept in _nearest_blocks(data, queries, k, bound, ids):
        rows[start:stop], distances[start:stop], lengths[start:stop] = found, dists, kept
    return rows, distances, lengths


def _nearest_blocks(data, queries, k, bound, ids, count=None):
    """:func:`nearest_within` one chunk of queries at a time: ``(start, stop, rows,
    distances, lengths)`` of the queries ``start:stop``; of the first ``count`` only where
    given."""
    n = data.shape[0]
    m = queries.shape[0] if count is None else count
    q = min(k + 1, n)
    # Long lists of the data's own points come from the grid query (pykdtree's cost grows as
    # k^2); it finds the same points at the same distances.
    grid = queries is data and (q >= GRID_K or (q >= BOUNDED_GRID_K and n >= BOUNDED_GRID_POINTS))
    query = _grid_query(data, q, GRID_LOOKED) if grid else None
    tree = None if grid else kdtree(data)
    ids = _NO_IDS if ids is None else np.ascontiguousarray(ids, np.int64)
    chunk = max(1, QUERY_ENTRIES // (k + 1))
    for start in range(0, m, chunk):
        stop = min(m, start + chunk)
        if grid:
            # Rows of the index width of knn_graph's, so that one signature of the grid query
            # serves both (a compile saved in a process that takes both).
            found = np.empty((stop - start, q), np.int32 if n < 2**31 else np.int64)
            dists = query(start, stop, found, bound * bound, n)
            found = found.astype(np.int64)
        else:
            dists, found = tree.query(queries[start:stop], k=q, distance_upper_bound=bound)
            dists = np.asarray(dists, np.float64).reshape(-1, q)
            found = np.asarray(found, np.int64).reshape(-1, q)
        if q < k + 1:  # as if the k + 1-th were beyond the bound
            pad = k + 1 - q
            dists = np.column_stack((dists, np.full((stop - start, pad), np.inf)))
            found = np.column_stack((found, np.full((stop - start, pad), n)))
        rows = np.empty((stop - start, k), np.int64)
        distances = np.empty((stop - start, k))
        lengths = np.empty(stop - start, np.int64)
        keep_nearest(dists, found, n, ids, rows, distances, lengths)
        yield start, stop, rows, distances, lengths


def candidates(data, queries, q, bound, block):
    """The ``q`` nearest of ``data`` strictly within ``bound`` of each of ``queries``, by the
    grid query whatever ``q``, ``block`` queries at a time: ``(start, stop, distances, rows)``,
    ``(stop - start, q)`` arrays sorted by distance, infinity and ``len(data)`` past the points
    found. The distances are exact, so the candidates of the pieces of a cloud give the whole
    cloud's lists (:func:`merge_candidates`)."""
    n, m = data.shape[0], queries.shape[0]
    have = min(q, n)
    query = _grid_query(data, have, GRID_LOOKED) if have else None
    for start in range(0, m, block):
        stop = min(m, start + block)
        distances = np.full((stop - start, q), np.inf)
        rows = np.full((stop - start, q), n, np.int64)
        if have:
            found = np.empty((stop - start, have), np.int32 if n < 2**31 else np.int64)
            distances[:, :have] = query(start, stop, found, bound * bound, n, queries)
            rows[:, :have] = found
        yield start, stop, distances, rows


def merge_candidates(distances, rows, k, missing):
    """:func:`nearest_within`'s lists of ``k`` from the :func:`candidates` of a cloud's pieces
    side by side (``(m, c)`` distances and rows in the whole cloud, ``missing`` where none;
    each piece's ``k + 1`` nearest, or more): ``(rows, lengths, order)``, ``order`` the
    columns of the candidates each kept entry came from."""
    m = distances.shape[0]
    # By distance, then row: the first k + 1 are the whole cloud's nearest, ties by row.
    order = np.lexsort((rows, distances), axis=1)[:, :k + 1]
    nearest = np.take_along_axis(distances, order, axis=1)
    found = np.take_along_axis(rows, order, axis=1)
    if order.shape[1] < k + 1:  # as if the k + 1-th were beyond the bound
        pad = k + 1 - order.shape[1]
        nearest = np.column_stack((nearest, np.full((m, pad), np.inf)))
        found = np.column_stack((found, np.full((m, pad), missing)))
        order = np.column_stack((order, np.zeros((m, pad), np.int64)))
    kept = np.empty((m, k), np.int64)
    lengths = np.empty(m, np.int64)
    keep_nearest(nearest, found, missing, _NO_IDS, kept, np.empty((m, k)), lengths)
    return kept, lengths, order[:, :k]


def bounded_graph(points, k, bound, rows=None, ids=None, first=None):
    """Lists of the ``k`` nearest points within distance ``bound`` of each of ``rows`` (all
    points by default; the ``first`` points where given, found as the lists of all are, to
    the bit), the point itself first (:func:`nearest_within`; ties ordered by ``ids`` where
    given), as a :class:`ListScales`; every other point's list is the point alone."""
    n = points.shape[0]
    queries = points if rows is None else points[rows]
    rows = (np.arange(n if first is None else first) if rows is None
            else np.asarray(rows, np.int64))
    dtype = np.int32 if n < 2**31 else np.int64
    counts = np.empty(rows.shape[0], np.int64)
    radius = np.zeros(n)
    nearest = np.zeros(n)
    # Each chunk's lists go straight to their place, in an array of k entries a query: the
    # (q, k) arrays of the whole query would take four times the lists' own memory, and
    # pieces joined at the end twice it.
    found_lists = np.empty(rows.shape[0] * k, dtype)
    end = 0
    for start, stop, found, dists, kept in _nearest_blocks(points, queries, k, bound, ids,
                                                           first):
        counts[start:stop] = kept
        ends = end + np.cumsum(kept)
        pack_rows(found, kept, ends - kept, found_lists)
        end = int(ends[-1])
        at = rows[start:stop]
        radius[at] = dists[np.arange(stop - start), kept - 1]
        nearest[at] = np.where(kept > 1, dists[:, min(1, k - 1)], 0.0)
    found_lists = found_lists[:end]
    lengths = np.ones(n, np.int64)
    lengths[rows] = counts
    indptr = np.concatenate(([0], np.cumsum(lengths)))
    if rows.shape[0] == n:  # every point's list, in the points' order
        indices = found_lists
    else:
        indices = np.arange(n, dtype=dtype).repeat(lengths)
        keep = np.arange(counts.max(initial=0)) < counts[:, None]
        indices[np.repeat(indptr[rows], counts) + np.nonzero(keep)[1]] = found_lists
    return ListScales(indptr, indices, radius, nearest)


def _tree_query(points, k):
    """``query(start, stop, rows)``: pykdtree's lists of those points into ``rows``; returns
    their distances."""
    tree = kdtree(points)

    def query(start, stop, rows):
        chunk_dists, chunk_idx = tree.query(points[start:stop], k=k)
        rows[:] = chunk_idx.reshape(-1, k)
        return np.ascontiguousarray(chunk_dists, dtype=np.float64).reshape(-1, k)

    return query


def _grid_query(points, k, looked=None):
    """Like :func:`_tree_query`, over a grid of cells about the k-th neighbour distance
    (``looked``: :func:`_grid_cell`'s)."""
    n = points.shape[0]
    low, high = _grid_box(points)
    extent = high - low
    cell = _grid_cell(points, k, extent, looked)
    dims = (extent / cell).astype(np.int64) + 1
    # Keys must fit 63 bits: a cloud spread too far on every axis widens the cells instead.
    while float(np.prod(dims.astype(np.float64))) > 2.0**62:
        cell *= 2.0
        dims = (extent / cell).astype(np.int64) + 1
    # Points beyond the box join its border cells: a query finds them among its candidates,
    # and their own queries widen their block until it covers the grid.
    coords = np.clip((points - low) / cell, 0, dims - 1).astype(np.int64)
    keys = (coords[:, 0] * dims[1] + coords[:, 1]) * dims[2] + coords[:, 2]
    # The keys are at least 0: as uint64 they sort alike.
    members = code_order(keys.view(np.uint64)).astype(np.int32 if n < 2**31 else np.int64)
    sorted_keys = keys[members]
    first = np.flatnonzero(np.diff(sorted_keys)) + 1
    cell_keys = np.ascontiguousarray(sorted_keys[np.concatenate(([0], first))])
    cell_start = np.concatenate(([0], first, [n])).astype(np.int64)
    cell_points = points[members]

    def query(start, stop, rows, bound2=np.inf, missing=0, queries=None):
        # Queries other than the points (``queries[start:stop]``) are looked up alike.
        chunk_dists = np.empty(rows.shape)
        grid_knn(points if queries is None else queries, cell_points, low, cell, dims,
                 cell_keys, cell_start, members, k, start, bound2, missing, rows, chunk_dists)
        return chunk_dists

    return query


#: The most points :func:`_grid_box` and :func:`_grid_cell` read: an evenly spread sample.
GRID_SAMPLE = 20_000
#: The grid of :func:`_grid_query` spans the middle of each axis's sample of coordinates,
#: from the ``OUTSIDE``-th to the ``1 - OUTSIDE``-th quantile, widened by that span on both
#: sides (and never beyond the bounding box): a stray point far from the rest would otherwise
#: stretch it, and its cells, until every query scanned the whole cloud (Autzen with a row 1e9
#: feet away: 117 s in the lists against under a second).
OUTSIDE = 0.001


def _grid_box(points):
    """Low and high corner of :func:`_grid_query`'s grid (:data:`OUTSIDE`), from the sample
    :func:`_grid_cell` reads."""
    low, high = bounds(points)
    sample = points[::max(1, points.shape[0] // GRID_SAMPLE)]
    inner_low, inner_high = np.quantile(sample, [OUTSIDE, 1.0 - OUTSIDE], axis=0)
    span = inner_high - inner_low
    return np.maximum(low, inner_low - span), np.minimum(high, inner_high + span)


def _grid_cell(points, k, extent, looked=None):
    """Cell edge: 1.1 times the 90th percentile of the k-th neighbour distance, estimated on an
    evenly spread sample, so that nearly every query finds its list among the 27 cells around it.

    The sample's distances are scaled by ``sqrt(sample / n)``, as on a surface (a
    two-dimensional density). Any edge gives exact lists; a poor one only costs time. With
    ``looked``, about that many of the sample's points are looked up, not all of them: the
    lists of a bounded query are ordered by index whatever the edge, so an edge from fewer
    lookups changes no bit there (:func:`knn_graph`'s tied lists keep the order of the full
    sample's edge).
    """
    n = points.shape[0]
    step = max(1, n // GRID_SAMPLE)
    sample = points[::step]
    m = sample.shape[0]
    cell = 0.0
    if m > k:
        at = sample if looked is None else sample[::max(1, m // looked)]
        dists, _ = kdtree(sample).query(at, k=k)
        cell = 1.1 * float(np.quantile(dists[:, -1], 0.9)) * np.sqrt(m / n)
    longest = float(extent.max())
    if not cell > 0.0:
        cell = longest if longest > 0.0 else 1.0
    return cell


def refresh_graph(graph, points):
    """``graph``'s lists re-sorted by the distances between the current ``points`` (in place),
    as a :class:`ListScales`: the next iteration keeps its neighbours but not stale orders or
    scales."""
    n = graph.indptr.shape[0] - 1
    radius = np.empty(n)
    nearest = np.empty(n)
    refresh_lists(points, graph.indptr, graph.indices, radius, nearest)
    return ListScales(graph.indptr, graph.indices, radius, nearest)


def neighbors(points, k=25, *, n_jobs=None):
    """Build the k-nearest-neighbour graph of a point cloud.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates (any real dtype; computed in float64).
    k : int, default 25
        List length, counting the point itself (docs/ALGORITHM.md: ``N_k(i)`` includes ``p_i``).
        At least 10 (the cubic fit's 10 coefficients) and at most ``n - 1``.
    n_jobs : int or None
        Threads for the repair kernel (see :func:`pssd_fast.denoise`).

    Returns
    -------
    NeighborGraph
        CSR arrays ``(indptr, indices, distances)`` in the caller's point order; each list is
        sorted by distance and starts with the point itself, also when exact duplicates tie with
        it at distance 0.

    Raises
    ------
    TypeError, ValueError
        For malformed points or an invalid ``k``.

    Notes
    -----
    The query runs on the points reordered along a Morton curve (better memory locality in
    the tree and in later kernels); results are mapped back to the caller's order.
    """
    pts, _ = as_points(interop.coordinates(points))
    k = check_k(k, pts.shape[0], denoising=False)
    with threads(n_jobs):
        return caller_order_graph(pts, k)


def caller_order_graph(points, k):
    """:func:`neighbors` on validated float64 points: query in Morton order, map back."""
    n = points.shape[0]
    order = curve_order(points)
    graph = knn_graph(points[order], k)
    indices = np.empty_like(graph.indices)
    distances = np.empty_like(graph.distances)
    indices.reshape(n, k)[order] = order[graph.indices.reshape(n, k)]
    distances.reshape(n, k)[order] = graph.distances.reshape(n, k)
    return NeighborGraph(graph.indptr, indices, distances)


def check_graph(graph, n_points, min_list=2):
    """Validate a caller-supplied graph for ``n_points`` points; return it with kernel dtypes."""
    if not isinstance(graph, tuple) or len(graph) != 3:
        raise TypeError("graph must be a NeighborGraph (indptr, indices, distances), as returned "
                        f"by pssd_fast.neighbors; got {type(graph).__name__}")
    indptr, indices, distances = (np.asarray(a) for a in graph)
    if indptr.dtype.kind not in "iu" or indices.dtype.kind not in "iu":
        raise TypeError("graph.indptr and graph.indices must be integer arrays; got "
                        f"{indptr.dtype} and {indices.dtype}")
    if indptr.shape != (n_points + 1,):
        raise ValueError(f"graph.indptr must have shape ({n_points + 1},) for {n_points} points; "
                         f"got {indptr.shape}: was the graph built for these points?")
    lengths = np.diff(indptr)
    if indptr[0] != 0 or (lengths < min_list).any():
        raise ValueError(f"graph.indptr must start at 0 and give every list at least {min_list} "
                         "entries")
    nnz = int(indptr[-1])
    if indices.shape != (nnz,) or distances.shape != (nnz,):
        raise ValueError(f"graph.indices and graph.distances must have shape ({nnz},); got "
                         f"{indices.shape} and {distances.shape}")
    if nnz and (indices.min() < 0 or indices.max() >= n_points):
        raise ValueError(f"graph.indices must lie in [0, {n_points}); was the graph built for "
                         "these points?")
    if (indices[indptr[:-1]] != np.arange(n_points)).any():
        raise ValueError("every list of graph must start with the point itself, as "
                         "pssd_fast.neighbors builds them")
    index_dtype = np.int32 if n_points < 2**31 else np.int64
    return NeighborGraph(np.ascontiguousarray(indptr, dtype=np.int64),
                         np.ascontiguousarray(indices, dtype=index_dtype),
                         np.ascontiguousarray(distances, dtype=np.float64))
