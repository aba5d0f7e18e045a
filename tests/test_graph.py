"""The kNN graph: brute-force agreement, self first under ties, caller order, validation."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import graph as graph_module
from pssd_fast.graph import check_graph, knn_graph, morton_order
from pssd_fast.kernels.order import gather_rows, scatter_rows

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
