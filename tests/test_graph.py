"""The kNN graph: brute-force agreement, self first under ties, caller order, validation; the
lists bounded by a radius."""
import numpy as np
import pytest
from pykdtree.kdtree import KDTree

import pssd_fast
from pssd_fast import graph as graph_module
from pssd_fast.graph import bounded_graph, check_graph, knn_graph, morton_order, nearest_within
from pssd_fast.kernels.graph import keep_nearest, pack_rows
from pssd_fast.kernels.knn import kth_smallest, select
from pssd_fast.kernels.order import gather_rows, scatter_rows, stable_argsort

from . import reference
from .conftest import CLOUDS


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_neighbors_match_brute_force(name):
    points = CLOUDS[name]()
    k = min(25, len(points) - 1)
    graph = pssd_fast.neighbors(points, k)
    lists, dists = reference.knn_lists(points, k)
    n = len(points)
    np.testing.assert_array_equal(graph.indptr, np.arange(0, n * k + 1, k))
    got = graph.indices.reshape(n, k)
    got_d = graph.distances.reshape(n, k)
    np.testing.assert_array_equal(got[:, 0], np.arange(n))
    np.testing.assert_allclose(got_d, np.array(dists), rtol=1e-12, atol=1e-15)
    assert np.all(np.diff(got_d, axis=1) >= 0)
    # Same neighbour sets except where distances tie at the list's end.
    for i in range(n):
        exact = np.array(dists[i]) < np.array(dists[i])[-1]
        assert set(np.array(lists[i])[exact]) <= set(got[i])
    # Stored distances are the true distances of the stored indices.
    np.testing.assert_allclose(
        got_d, np.linalg.norm(points[got] - points[:, None, :], axis=2), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_grid_query_matches_brute_force(name, monkeypatch):
    """The grid query (long lists) on every test cloud, degenerate ones included."""
    monkeypatch.setattr(graph_module, "GRID_K", 2)
    points = CLOUDS[name]()
    n = len(points)
    for k in sorted({min(3, n - 1), min(12, n - 1), n - 1}):
        graph = knn_graph(points, k)
        lists, dists = reference.knn_lists(points, k)
        got = graph.indices.reshape(n, k)
        got_d = graph.distances.reshape(n, k)
        np.testing.assert_array_equal(got[:, 0], np.arange(n))
        np.testing.assert_allclose(got_d, np.array(dists), rtol=1e-12, atol=1e-15)
        for i in range(n):
            exact = np.array(dists[i]) < np.array(dists[i])[-1]
            assert set(np.array(lists[i])[exact]) <= set(got[i])
            assert len(set(got[i])) == k
        np.testing.assert_allclose(
            got_d, np.linalg.norm(points[got] - points[:, None, :], axis=2), rtol=1e-12,
            atol=1e-15)


def test_grid_query_widens_its_search_where_the_grid_is_sparse(monkeypatch):
    """A far outlier and a dense clump: cells far from the k-th neighbour distance."""
    monkeypatch.setattr(graph_module, "GRID_K", 2)
    rng = np.random.default_rng(8)
    points = np.vstack([rng.normal(0, 0.01, (300, 3)), [[5.0, 5.0, 5.0]],
                        rng.uniform(-1, 1, (30, 3))])
    lists, dists = reference.knn_lists(points, 20)
    graph = knn_graph(points, 20)
    np.testing.assert_allclose(graph.distances.reshape(-1, 20), np.array(dists), rtol=1e-12)


def test_grid_and_tree_queries_agree_and_ignore_the_thread_count(monkeypatch):
    import numba
    points = CLOUDS["wavy"](3000)
    tree = knn_graph(points, 50)
    monkeypatch.setattr(graph_module, "GRID_K", 50)
    runs = []
    for threads in (1, numba.config.NUMBA_NUM_THREADS):
        previous = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            runs.append(knn_graph(points, 50))
        finally:
            numba.set_num_threads(previous)
    for a, b in zip(*runs):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(runs[0].indices, tree.indices)  # no ties in this cloud
    np.testing.assert_allclose(runs[0].distances, tree.distances, rtol=1e-15, atol=0)


@pytest.mark.parametrize("name", ["wavy", "duplicates"])
def test_chunked_query_and_lean_graph_match_one_query(name, monkeypatch):
    points = CLOUDS[name]()
    whole = knn_graph(points, 12)
    monkeypatch.setattr(graph_module, "QUERY_ENTRIES", 7 * 12)  # 7-point chunks, last short
    chunked = knn_graph(points, 12)
    lean = knn_graph(points, 12, keep_distances=False)
    for a, b in zip(whole, chunked):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(lean.indices, whole.indices)
    np.testing.assert_array_equal(lean.list_radius(), whole.list_radius())
    np.testing.assert_array_equal(lean.nearest_distance(), whole.nearest_distance())


@pytest.mark.parametrize("name", ["wavy", "duplicates", "tiny"])
def test_refreshed_lists_match_a_stable_sort(name):
    points = CLOUDS[name]()
    graph = knn_graph(points, 10)
    moved = points + np.random.default_rng(4).normal(0, 0.02, points.shape)
    if name == "duplicates":
        moved = points[:, ::-1].copy()  # still tied at distance 0, in a new geometry
    expected, dists = reference.resort_lists(moved, reference.graph_lists(graph))
    refreshed = graph_module.refresh_graph(graph, moved)
    np.testing.assert_array_equal(refreshed.indices, np.concatenate(expected))
    np.testing.assert_allclose(refreshed.list_radius(), [d[-1] for d in dists], rtol=1e-15)
    np.testing.assert_allclose(refreshed.nearest_distance(), [d[1] for d in dists], rtol=1e-15)


def test_self_first_with_more_twins_than_k():
    points = np.repeat(CLOUDS["wavy"](40), 15, axis=0)  # 15 copies > k = 10
    graph = pssd_fast.neighbors(points, 10)
    rows = graph.indices.reshape(-1, 10)
    np.testing.assert_array_equal(rows[:, 0], np.arange(len(points)))
    np.testing.assert_array_equal(graph.distances, 0.0)
    assert all(len(set(r)) == 10 for r in rows)


def test_morton_order_is_a_locality_preserving_permutation():
    points = CLOUDS["wavy"](2000)
    order = morton_order(points)
    np.testing.assert_array_equal(np.sort(order), np.arange(len(points)))
    step = np.linalg.norm(np.diff(points[order], axis=0), axis=1).mean()
    random_step = np.linalg.norm(np.diff(points, axis=0), axis=1).mean()
    assert step < random_step / 5
    np.testing.assert_array_equal(morton_order(np.zeros((5, 3))), np.arange(5))


@pytest.mark.parametrize("points, error, match", [
    (np.zeros((3, 100)), ValueError, r"shape \(n, 3\); got shape \(3, 100\).*transpose"),
    (np.full((4, 3), np.nan), ValueError, "NaN or Inf in 4 row"),
    (np.zeros((0, 3)), ValueError, "points is empty"),
    (np.zeros((4, 3), complex), TypeError, "must hold real numbers"),
])
def test_morton_order_names_bad_points(points, error, match):
    """The public morton_order checks its points as denoise does."""
    with pytest.raises(error, match=match):
        pssd_fast.morton_order(points)


@pytest.mark.parametrize("name", sorted(CLOUDS))
def test_morton_order_matches_the_reference(name):
    points = CLOUDS[name]() * 1e3 + [5e5, -4e6, 300.0]
    np.testing.assert_array_equal(morton_order(points), reference.morton_order(points))


def test_row_permutations_are_inverse():
    points = CLOUDS["sphere"]()
    order = np.random.default_rng(5).permutation(len(points))
    offset = np.array([1.0, -2.0, 3.0])
    moved = np.empty_like(points)
    gather_rows(points, order, offset, moved)
    np.testing.assert_array_equal(moved, points[order] - offset)
    back = np.empty_like(points)
    scatter_rows(moved, order, offset, back)
    np.testing.assert_allclose(back, points, rtol=1e-15, atol=1e-15)


def _stable_order(keys):
    """The plain stable sort: rows by key, ties in row order (Python's sort is stable)."""
    return np.array(sorted(range(len(keys)), key=lambda i: int(keys[i])), dtype=np.int64)


@pytest.mark.parametrize("case", ["random", "few", "sorted", "reversed", "equal", "top bit",
                                  "one", "none"])
def test_the_radix_sort_gives_the_stable_order(case):
    rng = np.random.default_rng(3)
    keys = {"random": rng.integers(0, 2**63, 5000, dtype=np.uint64),
            "few": rng.integers(0, 4, 5000).astype(np.uint64) << np.uint64(40),
            "sorted": np.sort(rng.integers(0, 2**30, 3000).astype(np.uint64)),
            "reversed": np.sort(rng.integers(0, 2**30, 3000).astype(np.uint64))[::-1].copy(),
            "equal": np.full(2000, 2**64 - 1, np.uint64),
            "top bit": rng.integers(0, 2, 3000).astype(np.uint64) << np.uint64(63),
            "one": np.array([5], np.uint64), "none": np.zeros(0, np.uint64)}[case]
    order = np.full(keys.shape[0], -1, np.int64)
    stable_argsort(keys, order)
    np.testing.assert_array_equal(order, _stable_order(keys))


@pytest.mark.parametrize("radix_points", [0, 10**9])
def test_code_order_is_numpy_s_stable_argsort_either_way(radix_points, monkeypatch):
    monkeypatch.setattr(graph_module, "RADIX_POINTS", radix_points)
    codes = np.random.default_rng(4).integers(0, 2**12, 20000).astype(np.uint64)
    np.testing.assert_array_equal(graph_module.code_order(codes),
                                  np.argsort(codes, kind="stable"))


def test_neighbors_in_caller_order_for_any_permutation():
    points = CLOUDS["sphere"]()
    perm = np.random.default_rng(0).permutation(len(points))
    a = pssd_fast.neighbors(points, 12)
    b = pssd_fast.neighbors(points[perm], 12)
    inv = np.argsort(perm)
    rows_b = perm[b.indices.reshape(-1, 12)][inv]
    np.testing.assert_array_equal(np.sort(a.indices.reshape(-1, 12), 1), np.sort(rows_b, 1))


def test_check_graph_rejects_foreign_graphs():
    points = CLOUDS["wavy"]()
    graph = pssd_fast.neighbors(points, 12)
    assert check_graph(graph, len(points)).indices.dtype == np.int32
    with pytest.raises(TypeError, match="NeighborGraph"):
        check_graph(graph.indices, len(points))
    with pytest.raises(ValueError, match="built for these points"):
        check_graph(graph, len(points) + 1)
    shuffled = graph._replace(indices=np.roll(graph.indices, 1))
    with pytest.raises(ValueError, match="start with the point itself"):
        check_graph(shuffled, len(points))
    with pytest.raises(ValueError, match=r"lie in \[0"):
        check_graph(graph._replace(indices=graph.indices + len(points)), len(points))


def test_grid_query_with_outliers_far_away_on_every_axis(monkeypatch):
    """Keys stay within 63 bits and far outliers find their lists in few rounds."""
    monkeypatch.setattr(graph_module, "GRID_K", 2)
    rng = np.random.default_rng(12)
    surface = np.column_stack([rng.uniform(0, 1, (2000, 2)), rng.normal(0, 1e-3, 2000)])
    far = np.array([[1e6, 1e6, 1e6], [-1e6, 3e5, -2e6], [5e5, -1e6, 1e6]])
    uniform = rng.uniform(-0.2, 1.2, (40, 3))
    points = np.vstack([surface, far, uniform])
    lists, dists = reference.knn_lists(points, 15)
    graph = knn_graph(points, 15)
    np.testing.assert_allclose(graph.distances.reshape(-1, 15), np.array(dists), rtol=1e-12)


def test_far_points_leave_the_grid_to_the_others(monkeypatch):
    """Rows 1e9 and 1e300 away join the border cells of a grid that spans the other points, so
    its cells stay about a list's reach (they stretched until every query read the whole
    cloud: Autzen's lists took 117 s instead of under one); every list stays exact, theirs
    too."""
    monkeypatch.setattr(graph_module, "GRID_K", 2)
    rng = np.random.default_rng(13)
    surface = np.column_stack([rng.uniform(0, 1, (3000, 2)), rng.normal(0, 1e-3, 3000)])
    points = np.vstack([surface, [[1e9, 1e9, 1e9], [0.5, -1e300, 0.5], [2.0, 0.5, 0.0]]])
    low, high = graph_module._grid_box(points)
    bottom, top = surface.min(axis=0), surface.max(axis=0)
    assert (low >= bottom - (top - bottom)).all() and (high <= top + (top - bottom)).all()
    lists, dists = reference.knn_lists(points, 15)
    graph = knn_graph(points, 15)
    np.testing.assert_allclose(graph.distances.reshape(-1, 15), np.array(dists), rtol=1e-12)


def _lattice(side=12):
    """A square lattice of unit spacing in the plane z = 0: ties at every list length."""
    g = np.arange(float(side))
    return np.column_stack([np.repeat(g, side), np.tile(g, side), np.zeros(side * side)])


#: The bounded lists' clouds: the shared ones and a lattice; each with list lengths and bounds
#: (none of them a lattice distance: at the bound itself, see the test below).
BOUNDED = {**CLOUDS, "lattice": _lattice}


def _check_bounded(found, want, n):
    """``nearest_within``'s ``(rows, distances, lengths)`` against the reference's lists."""
    rows, dists, lengths = found
    for i, (members, distance) in enumerate(want):
        count = len(members)
        assert lengths[i] == count, i
        np.testing.assert_array_equal(rows[i, :count], members, err_msg=str(i))
        np.testing.assert_allclose(dists[i, :count], distance, rtol=1e-12, atol=1e-15)
        assert (rows[i, count:] == n).all() and np.isinf(dists[i, count:]).all()


@pytest.mark.parametrize("name", sorted(BOUNDED))
def test_nearest_within_matches_brute_force(name, monkeypatch):
    """The points nearer than the k + 1-th (none of a tie at the cut) and within the bound,
    by distance then index: from the tree (queries apart from the data) and, for lists of
    BOUNDED_GRID_K or more, from the grid query (the data's own points, at any size here)."""
    monkeypatch.setattr(graph_module, "BOUNDED_GRID_POINTS", 0)
    points = BOUNDED[name]()
    n = len(points)
    spread = float(np.ptp(points, axis=0).max())
    for k in sorted({min(4, n - 1), min(12, n - 1), min(graph_module.BOUNDED_GRID_K, n - 1),
                     n - 1}):
        for bound in (np.inf, 0.2113 * spread):
            want = reference.nearest_within(points, points, k, bound)
            _check_bounded(nearest_within(points, points, k, bound), want, n)
            _check_bounded(nearest_within(points, points.copy(), k, bound), want, n)


def test_nearest_within_drops_a_tie_at_the_cut():
    """On the lattice an inner point's 4 nearest others lie at 1 and the next 4 at sqrt(2):
    lists of 4 keep the point alone, lists of 5 to 8 the point and its 4 nearest."""
    points = _lattice()
    inner = 5 * 12 + 5
    for k, count in ((4, 1), (5, 5), (8, 5), (9, 9)):
        rows, dists, lengths = nearest_within(points, points[inner:inner + 1], k, np.inf)
        assert lengths[0] == count
        # Ties in distance by index.
        np.testing.assert_array_equal(rows[0, :count], sorted(
            range(len(points)), key=lambda j: (np.linalg.norm(points[j] - points[inner]), j))[
            :count])


def test_nearest_within_drops_a_point_at_the_bound_itself_from_either_query(monkeypatch):
    """Both queries keep only points strictly within the bound (pykdtree's
    distance_upper_bound): on a lattice with a neighbour at the bound itself, the grid's lists
    and the tree's are the reference's."""
    monkeypatch.setattr(graph_module, "BOUNDED_GRID_POINTS", 0)
    points = _lattice()
    want = reference.nearest_within(points, points, 130, 1.0)
    _check_bounded(nearest_within(points, points, 130, 1.0), want, len(points))  # the grid's
    _check_bounded(nearest_within(points, points.copy(), 130, 1.0), want, len(points))


@pytest.mark.parametrize("name", sorted(BOUNDED))
@pytest.mark.parametrize("pieces", [1, 3])
def test_candidates_of_pieces_merge_into_the_whole_cloud_s_lists(name, pieces):
    """Each piece's candidates (the grid's k + 1 nearest within the bound, rows numbered in
    the whole cloud) side by side, merged: the reference's lists of the whole cloud, ties at
    the cut and at one distance included (the lattice), lists longer than a piece too."""
    points = BOUNDED[name]()
    n = len(points)
    queries = points[::3]
    cuts = np.linspace(0, n, pieces + 1).astype(int)
    spread = float(np.ptp(points, axis=0).max())
    for k in sorted({min(4, n - 1), min(12, n - 1), n - 1}):
        for bound in (np.inf, 0.2113 * spread):
            distances, rows = [], []
            for a, b in zip(cuts[:-1], cuts[1:]):
                (_, _, d, r), = graph_module.candidates(points[a:b], queries, k + 1, bound,
                                                        len(queries))
                distances.append(d)
                rows.append(np.where(r < b - a, r + a, n))
            kept, lengths, order = graph_module.merge_candidates(
                np.hstack(distances), np.hstack(rows), k, n)
            want = reference.nearest_within(points, queries, k, bound)
            for i, (members, _) in enumerate(want):
                assert lengths[i] == len(members), (k, bound, i)
                np.testing.assert_array_equal(kept[i, :lengths[i]], members)
                # The columns each kept entry came from hold it.
                np.testing.assert_array_equal(
                    np.hstack(rows)[i, order[i, :lengths[i]]], members)


@pytest.mark.parametrize("lengths", [[3, 0, 5, 1], [5, 5, 5, 5], [0, 0, 0, 0], [2]])
def test_rows_packed_end_to_end_are_numpy_s_gather(lengths):
    """``pack_rows`` against the loop it replaces: each row's first entries, in row order,
    into a narrower integer type (the lists' own)."""
    lengths = np.array(lengths, np.int64)
    rows = np.random.default_rng(len(lengths)).integers(0, 1000, (len(lengths), 5))
    want = [int(v) for r, n in zip(rows, lengths) for v in r[:n]]
    out = np.full(len(want) + 2, -1, np.int32)
    ends = 1 + np.cumsum(lengths)  # packed from out[1] on
    pack_rows(rows, lengths, ends - lengths, out)
    assert out[1:-1].tolist() == want and out[0] == out[-1] == -1


#: Squared distances for the grid query's selection: random, tied, ordered, and single.
SELECTED = {
    "random": np.random.default_rng(5).random(300),
    "ties": np.random.default_rng(6).integers(0, 4, 300).astype(np.float64),
    "equal": np.full(50, 2.5),
    "increasing": np.arange(100.0),
    "decreasing": np.arange(100.0)[::-1].copy(),
    "zeros and one": np.array([0.0] * 30 + [1.0]),
    "one": np.array([7.0]),
}


@pytest.mark.parametrize("name", sorted(SELECTED))
def test_the_selection_of_the_kth_distance_is_numpy_s(name):
    """``select`` (in place) and ``kth_smallest`` (among the values at most a little over a
    guess, else all) give the j-th smallest value as a full sort does, whatever the guess."""
    values = SELECTED[name]
    m = values.shape[0]
    ordered = np.sort(values)
    for j in sorted({0, m // 3, m // 2, m - 1}):
        scratch = values.copy()
        assert select(scratch, m, j) == ordered[j]
        assert sorted(scratch) == list(ordered)  # reordered, nothing lost
        for guess in (0.0, ordered[j], np.nextafter(ordered[j], 0), ordered[0], ordered[-1],
                      np.inf):
            assert kth_smallest(values, m, j + 1, guess, np.empty(m)) == ordered[j], guess


def _both_queries(monkeypatch, points, k, bound):
    """``nearest_within(points, points, k, bound)`` from the tree and from the grid."""
    monkeypatch.setattr(graph_module, "BOUNDED_GRID_POINTS", 0)
    found = []
    for first in (10**9, 2):
        monkeypatch.setattr(graph_module, "BOUNDED_GRID_K", first)
        found.append(nearest_within(points, points, k, bound))
    return found


def test_the_grid_and_the_tree_give_the_same_bounded_lists_to_the_bit(monkeypatch):
    """Where the grid query serves the bounded lists, they are the tree's, bit for bit: on a
    quantised cloud full of ties, at a bound equal to one of its distances and a unit in the
    last place either side; and where a squared distance is below the square of the bound
    while its root rounds to the bound (pykdtree's bound is on the squares)."""
    k = graph_module.BOUNDED_GRID_K  # the grid's shortest lists (the patches below move it)
    rng = np.random.default_rng(4)
    points = np.unique(np.round(rng.normal(size=(3000, 3)) * [1.0, 1.0, 0.05], 2), axis=0)
    at = float(np.linalg.norm(points[0] - KDTree(points).query(points[:1], k=60)[1][0, 40]))
    for bound in (at, np.nextafter(at, 0), np.nextafter(at, 1)):
        tree, grid = _both_queries(monkeypatch, points, k, bound)
        for a, b in zip(grid, tree):
            np.testing.assert_array_equal(a, b, err_msg=repr(bound))
    # A point at (u, v, 0) from the origin, its distance's root the bound, its square below
    # the bound's: the tree keeps it.
    for u in rng.uniform(0.5, 0.8, 100):
        v = 0.9
        squared = u * u + v * v
        bound = float(np.sqrt(squared))
        if squared < bound * bound:
            break
    else:
        raise AssertionError("no such point found")
    near = rng.uniform(-0.1, 0.1, (20, 3))
    far = rng.uniform(3.0, 4.0, (200, 3))
    points = np.vstack([[0.0, 0.0, 0.0], [u, v, 0.0], near, far])
    tree, grid = _both_queries(monkeypatch, points, k, bound)
    assert 1 in tree[0][0, :tree[2][0]]
    for a, b in zip(grid, tree):
        np.testing.assert_array_equal(a, b)


def test_long_bounded_lists_of_a_small_cloud_come_from_the_grid(monkeypatch):
    """Below BOUNDED_GRID_POINTS, bounded lists of GRID_K or more come from the grid query, as
    the unbounded lists do (pykdtree's cost grows as k^2), and they are the tree's lists."""
    rng = np.random.default_rng(8)
    points = np.column_stack([rng.uniform(0, 1, (3000, 2)), rng.normal(0, 0.01, 3000)])
    k, bound = graph_module.GRID_K, 0.15
    assert len(points) < graph_module.BOUNDED_GRID_POINTS
    made = []
    grid_query = graph_module._grid_query
    monkeypatch.setattr(graph_module, "_grid_query", lambda *a: made.append(a) or grid_query(*a))
    grid = nearest_within(points, points, k, bound)
    assert made
    nearest_within(points, points, k - 2, bound)  # a query of k - 1: the tree
    assert len(made) == 1
    monkeypatch.setattr(graph_module, "GRID_K", 10**9)
    tree = nearest_within(points, points, k, bound)
    assert len(made) == 1
    assert (grid[2] < k).any() and (grid[2] == k).any()  # the bound and the k + 1-th both cut
    for a, b in zip(grid, tree):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("k", [20, graph_module.BOUNDED_GRID_K + 10])
def test_a_bounded_list_depends_only_on_the_points_within_its_bound(k, monkeypatch):
    """What tiles rely on: the lists of a block of points computed on any subset holding every
    point within the bound of them (a tile and its halo) are their lists on the whole cloud,
    bit for bit (the whole cloud's own lists of BOUNDED_GRID_K or more come from the grid
    query, a subset's from the tree)."""
    monkeypatch.setattr(graph_module, "BOUNDED_GRID_POINTS", 0)
    rng = np.random.default_rng(21)
    # Dense near x = 0, sparse near x = 1: some lists end at the k + 1-th, others at the bound.
    xy = rng.uniform(0, 1, (4000, 2)) ** [3.0, 1.0]
    points = np.column_stack([xy, rng.normal(0, 0.004, 4000)])
    bound = 0.05
    block = np.flatnonzero((points[:, 0] < 0.3) & (points[:, 1] < 0.4))
    near = KDTree(points).query(points[block], k=len(points), distance_upper_bound=bound)[1]
    halo = np.unique(near[near < len(points)])
    # Some points beyond the bound too, and not all of them: they change nothing.
    beyond = np.setdiff1d(rng.choice(len(points), 800, replace=False), halo)
    subset = np.sort(np.concatenate([halo, beyond]))
    whole_rows, whole_dists, whole_lengths = nearest_within(points, points, k, bound)
    rows, dists, lengths = nearest_within(points[subset], points[block], k, bound)
    np.testing.assert_array_equal(lengths, whole_lengths[block])
    assert (lengths < k).any() and (lengths == k).any()  # the bound and the k + 1-th both cut
    keep = np.arange(k) < lengths[:, None]
    np.testing.assert_array_equal(subset[rows[keep]], whole_rows[block][keep])
    np.testing.assert_array_equal(dists[keep], whole_dists[block][keep])


@pytest.mark.parametrize("name", ["wavy", "sphere", "plane", "collinear", "tiny", "lattice"])
def test_bounded_graph_matches_brute_force(name):
    """CSR lists of the chosen rows (all by default), the point itself first; every other
    point's list is the point alone; the radius and the nearest other distance of each list
    (0 for a list of the point alone). Distinct positions (the method's means and points)."""
    points = BOUNDED[name]()
    n = len(points)
    k = min(12, n - 1)
    bound = 0.3 * float(np.ptp(points, axis=0).max())
    for rows in (None, np.arange(0, n, 3)):
        lists = bounded_graph(points, k, bound, rows)
        chosen = np.arange(n) if rows is None else rows
        want = dict(zip(chosen, reference.nearest_within(points, points[chosen], k, bound)))
        for i in range(n):
            members, distance = want.get(i, (np.array([i]), np.zeros(1)))
            got = lists.indices[lists.indptr[i]:lists.indptr[i + 1]]
            np.testing.assert_array_equal(got, members, err_msg=f"{name} {i}")
            assert got[0] == i
            assert lists.radius[i] == pytest.approx(distance[-1], rel=1e-12, abs=1e-15)
            second = distance[1] if len(distance) > 1 else 0.0
            assert lists.nearest[i] == pytest.approx(second, rel=1e-12, abs=1e-15)


def test_keep_nearest_on_hand_made_rows():
    """Rows as a tree returns them (ties in any order, infinite beyond the bound): the entries
    nearer than the last, by distance then index."""
    dists = np.array([[0.0, 1.0, 1.0, 2.0, 2.0],
                      [0.0, 1.0, 1.0, 1.0, 1.0],
                      [0.0, 0.5, np.inf, np.inf, np.inf],
                      [0.0, 0.5, 0.7, 0.9, 3.0]])
    found = np.array([[5, 9, 3, 7, 1], [2, 8, 6, 4, 0], [4, 1, 10, 10, 10], [3, 0, 2, 1, 6]])
    kept = np.empty((4, 4), np.int64)
    kept_dists = np.empty((4, 4))
    lengths = np.empty(4, np.int64)
    keep_nearest(dists, found, 10, np.empty(0, np.int64), kept, kept_dists, lengths)
    np.testing.assert_array_equal(lengths, [3, 1, 2, 4])
    np.testing.assert_array_equal(kept, [[5, 3, 9, 10], [2, 10, 10, 10], [4, 1, 10, 10],
                                         [3, 0, 2, 1]])
    np.testing.assert_array_equal(kept_dists[:, 0], 0.0)
    assert np.isinf(kept_dists[0, 3]) and np.isinf(kept_dists[1, 1:]).all()
    # Ties by ids where given (a tile's points by their places in the whole cloud).
    keep_nearest(dists, found, 10, np.arange(11)[::-1].copy(), kept, kept_dists, lengths)
    np.testing.assert_array_equal(kept[0], [5, 9, 3, 10])


@pytest.mark.parametrize("seed", range(4))
def test_the_high_corners_cell_code_has_the_bits_of_the_largest(seed):
    # The tiled binning sizes its histogram of cell codes from the high corner's code alone.
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(3000, 3)) * rng.uniform(0.1, 1000.0, size=3)
    low, high = graph_module.bounds(points)
    edge = float(rng.uniform(0.001, 1.0)) * (high - low).max() / 50
    top = int(((high - low) * (1.0 / edge)).max())
    shift = max(0, top.bit_length() - graph_module.MORTON_BITS)
    codes, _ = graph_module.cell_keys(points, low, edge, shift)
    corner, _ = graph_module.cell_keys(high[None, :], low, edge, shift)
    assert int(corner[0]).bit_length() == int(codes.max()).bit_length()
    assert corner[0] >= codes.max()


def _inside_reference(points, boxes):
    """Plain loops: whether each point lies in some box, faces included."""
    out = []
    for p in points:
        out.append(any(all(box[0][a] <= p[a] <= box[1][a] for a in range(3)) for box in boxes))
    return np.array(out, np.bool_)


@pytest.mark.parametrize("seed", range(3))
def test_points_inside_any_box_match_a_loop(seed):
    from pssd_fast.kernels.boxes import inside_any

    rng = np.random.default_rng(seed)
    corners = rng.uniform(-1.0, 1.0, size=(7, 2, 3))
    boxes = np.stack([corners.min(axis=1), corners.max(axis=1)], axis=1)
    points = rng.uniform(-1.2, 1.2, size=(2000, 3))
    points[:14] = boxes.reshape(-1, 3)  # on the corners themselves
    points[14, :] = [boxes[0, 0, 0], boxes[0, 1, 1], 0.5 * (boxes[0, 0, 2] + boxes[0, 1, 2])]
    for pts, bxs in ((points, boxes), (points, boxes[:0]), (points[:0], boxes),
                     (points, boxes[:1])):
        out = np.empty(pts.shape[0], np.bool_)
        inside_any(pts, bxs, out)
        np.testing.assert_array_equal(out, _inside_reference(pts, bxs))
    assert out[:2].all() and out.any() and not out.all()


def _near_reference(points, centres, radius):
    """Plain loops: whether each point's squared distance to some centre is at most
    ``radius ** 2``."""
    out = []
    for p in points:
        out.append(any((c[0] - p[0]) ** 2 + (c[1] - p[1]) ** 2 + (c[2] - p[2]) ** 2
                       <= radius * radius for c in centres))
    return np.array(out, np.bool_)


@pytest.mark.parametrize("dense", [True, False])
@pytest.mark.parametrize("case", ["random", "clustered", "one centre", "coincident",
                                  "radius 0", "spread", "far points", "empty"])
def test_points_near_centres_match_a_loop(case, dense, monkeypatch):
    """The grid of the centres (graph.near_centres, kernels.boxes.near_any) against loops, on
    random and degenerate inputs; points at exactly the radius are near. With a table of
    every cell and (as larger grids) with binary searches."""
    from pssd_fast.graph import near_centres

    if not dense:
        monkeypatch.setattr(graph_module, "DENSE_CELLS", 0)

    rng = np.random.default_rng(5)
    points, centres, radius = rng.uniform(size=(800, 3)), rng.uniform(size=(40, 3)), 0.07
    if case == "clustered":
        centres = 0.5 + rng.normal(0.0, 0.01, (40, 3))
    elif case == "one centre":
        centres = centres[:1]
    elif case == "coincident":
        centres = np.repeat(centres[:1], 9, axis=0)
        points[:5] = centres[0]
    elif case == "radius 0":
        radius = 0.0
        points[:5] = centres[3]
    elif case == "spread":  # 2^20 cells an axis would not reach: wider cells
        centres = centres * [1e9, 1.0, 1.0]
        points[:100] = centres[rng.integers(0, 40, 100)] + 0.01
    elif case == "far points":
        points[:10] = [1e300, 0.0, 0.0]
        points[10:20] = -1e12
    elif case == "empty":
        np.testing.assert_array_equal(near_centres(points, centres[:0], radius), False)
        assert near_centres(points[:0], centres, radius).shape == (0,)
        return
    # Points at exactly the radius along an axis (binary fractions: no rounding).
    centres[0], radius = [0.5, 0.25, 0.75], radius and 0.0625
    points[50:53] = centres[0] + np.eye(3) * radius
    want = _near_reference(points, centres, radius)
    np.testing.assert_array_equal(near_centres(points, centres, radius), want)
    assert want[50:53].all()
    if case in ("random", "far points", "spread"):
        assert not want.all()


def test_regions_near_holds_a_hair_more():
    from pssd_fast import regions

    rng = np.random.default_rng(6)
    points, centres = rng.uniform(size=(500, 3)), rng.uniform(size=(7, 3))
    want = np.array([min(np.linalg.norm(p - c) for c in centres) <= 0.2 for p in points])
    np.testing.assert_array_equal(regions.near(points, centres, 0.2), want)
    assert 0 < want.sum() < 500
    assert not regions.near(points, centres[:0], 0.2).any()
    assert regions.near(points[:0], centres, 0.2).shape == (0,)


def _parts_reference(codes, weights, shift, most):
    """The bins of :func:`pssd_fast.regions.parts` by recursion on Python integers: a bin of
    more than ``most`` points split into bins of the next ``PREFIX_BITS`` bits, then a greedy
    walk over the bins in order; the first code of each part."""
    from pssd_fast.regions import PREFIX_BITS

    def leaves(members, first, width):
        if sum(weights[i] for i in members) <= most or width == 0:
            return [(first, sum(weights[i] for i in members))]
        finer = max(0, width - PREFIX_BITS)
        found = {}
        for i in members:
            found.setdefault(int(codes[i]) >> finer << finer, []).append(i)
        return [leaf for key in sorted(found) for leaf in leaves(found[key], key, finer)]

    top = {}
    for i in range(len(codes)):
        top.setdefault(int(codes[i]) >> shift << shift, []).append(i)
    bins = [leaf for key in sorted(top) for leaf in leaves(top[key], key, shift)]
    firsts, filled = [], 0
    for first, count in bins:
        if not firsts or (filled and filled + count > most):
            firsts.append(first)
            filled = 0
        filled += count
    return firsts


@pytest.mark.parametrize("most", [1, 5, 12, 1000])
@pytest.mark.parametrize("shift", [0, 7, 42])
@pytest.mark.parametrize("crowded", [False, True])
def test_regions_cut_codes_into_parts_of_at_most_most_points(most, shift, crowded):
    """Parts are runs of codes as full as fit ``most``; a bin of the first bits that holds more
    is split by the next bits (crowded: most codes within one bin of the first bits, as a far
    point leaves them), so only points of one code make a fuller part."""
    from pssd_fast import regions

    rng = np.random.default_rng(most + shift)
    top = 1 << (regions.PREFIX_BITS + shift)
    codes = rng.integers(0, top, 60).astype(np.uint64)
    if crowded:
        codes[:50] = rng.integers(0, max(1, top >> 30), 50).astype(np.uint64)
    codes[5:9] = codes[4]  # points of one code
    weights = rng.integers(1, 9, codes.shape[0])
    found, inverse = np.unique(codes >> np.uint64(shift), return_inverse=True)
    counts = np.bincount(inverse, weights).astype(np.int64)
    summed = regions.histogram([(found[:20], counts[:20]), (found[20:], counts[20:])])
    calls = []

    def refine(split):
        calls.append(split)
        half = codes.shape[0] // 2  # two tasks' histograms
        return [regions.binned(codes[:half], split, weights[:half]),
                regions.binned(codes[half:], split, weights[half:])]

    firsts = regions.parts(summed, shift, most, refine)
    assert firsts.tolist() == _parts_reference(codes, weights, shift, most)
    part = regions.part_of(firsts, codes)
    held = np.bincount(part, weights)
    distinct = np.array([np.unique(codes[part == p]).shape[0] for p in range(firsts.shape[0])])
    assert ((held <= most) | (distinct == 1)).all()
    assert bool(calls) == bool(shift and (counts > most).any())


@pytest.mark.parametrize("shift", [0, 3])
def test_cell_order_sorts_by_code_then_coordinates_stably(shift):
    """Codes of one cell each (shift 0) or of several (coarser codes): the order is numpy's
    stable lexicographic sort by code, then the coordinates, and each cell starts where its
    coordinates first appear in it."""
    rng = np.random.default_rng(shift)
    points = rng.uniform(0.0, 40.0, (3000, 3))
    code, cells = graph_module.cell_keys(points, np.zeros(3), 1.0, shift)
    assert (np.unique(code).shape[0] < np.unique(cells, axis=0).shape[0]) == (shift > 0)
    order, starts = graph_module.cell_order(code, cells)
    np.testing.assert_array_equal(order, np.lexsort((cells[:, 2], cells[:, 1], cells[:, 0],
                                                     code)))
    keys = cells[order]
    for first, end in zip(starts[:-1], starts[1:]):
        assert (keys[first:end] == keys[first]).all()
    assert starts[-1] == 3000 and np.unique(keys[starts[:-1]], axis=0).shape[0] == len(starts) - 1
