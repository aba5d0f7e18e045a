"""The edges route's pass (pssd_fast.routes.edges) against the references."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets
from pssd_fast.routes import edges
from pssd_fast.progress import Clock

from . import reference


def _folded(n, seed, noise=0.002):
    """Points on two faces meeting at a right-angled edge, with noise: a feature to sharpen."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n)
    points = np.where((u < 0)[:, None], np.column_stack((u, v, np.zeros(n))),
                      np.column_stack((np.zeros(n), v, u)))
    return points + rng.normal(0.0, noise, points.shape)


@pytest.mark.parametrize("n, k, share", [(300, 12, 0.3), (200, 200, 0.5), (150, 16, 1.0),
                                         (120, 10, 0.0)])
def test_zone_lists_are_the_flagged_points_nearest_and_the_others_alone(n, k, share):
    points = np.random.default_rng(n).normal(size=(n, 3))
    rows = np.flatnonzero(np.arange(n) < share * n)
    graph = edges.zone_lists(points, rows, k)
    expected, distances = reference.knn_lists(points, k)
    got = reference.graph_lists(graph)
    flagged = np.isin(np.arange(n), rows)
    for i in range(n):
        if flagged[i]:
            np.testing.assert_array_equal(got[i], expected[i])
            assert graph.radius[i] == pytest.approx(distances[i][-1], rel=1e-12)
            assert graph.nearest[i] == pytest.approx(distances[i][1], rel=1e-12)
        else:
            assert list(got[i]) == [i] and graph.radius[i] == 0.0


def test_zone_lists_in_chunks_are_one_query(monkeypatch):
    points = np.random.default_rng(5).normal(size=(500, 3))
    rows = np.arange(1, 500, 3)
    whole = edges.zone_lists(points, rows, 20)
    monkeypatch.setattr(edges, "QUERY_ENTRIES", 45)  # chunks of 2 rows
    for got, want in zip(edges.zone_lists(points, rows, 20), whole):
        np.testing.assert_array_equal(got, want)


def test_zone_lists_on_a_plane_put_each_point_first():
    """Coplanar points (a degenerate surface for the fits; distances still distinct)."""
    points = np.random.default_rng(3).uniform(size=(80, 3)) * [1.0, 1.0, 0.0]
    rows = np.arange(0, 80, 2)
    got = reference.graph_lists(edges.zone_lists(points, rows, 20))
    assert all(got[i][0] == i for i in range(80))


@pytest.mark.parametrize("m, fraction, radius", [(200, 0.15, 0.3), (50, 0.01, 0.0),
                                                 (40, 1.0, 0.5), (60, 0.15, 10.0)])
def test_zones_flag_the_top_features_and_their_surroundings(monkeypatch, m, fraction, radius):
    rng = np.random.default_rng(m)
    surface = rng.uniform(size=(m, 3))
    feature = np.round(rng.uniform(size=m), 1)  # ties, broken by row
    monkeypatch.setitem(edges.EDGES, "fraction", fraction)
    np.testing.assert_array_equal(edges.zones(surface, feature, radius),
                                  reference.zones(surface, feature, radius, fraction))


@pytest.mark.parametrize("n, share, k, iterations", [(220, 0.4, 16, 2), (90, 1.0, 12, 1),
                                                     (60, 0.1, 60, 2)])
def test_the_pass_is_the_references(monkeypatch, n, share, k, iterations):
    monkeypatch.setitem(edges.EDGES, "iterations", iterations)
    points = _folded(n, seed=n)
    order = np.argsort(np.abs(points[:, 0]) + np.abs(points[:, 2]), kind="stable")
    flagged = np.zeros(n, bool)
    flagged[order[:int(share * n)]] = True  # nearest the edge
    rng = np.random.default_rng(1)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[:, 2] = np.abs(normals[:, 2])
    moved, out, held = edges.sharpen(points, normals, flagged, None, False, k, 0.05,
                                     Clock(None, 0, 1))
    want, want_normals = reference.edges_pass(points, normals, flagged, k, iterations)
    assert not held.any()
    np.testing.assert_allclose(moved, want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(out, want_normals, rtol=0, atol=1e-7)


def test_the_pass_takes_given_normals_first(monkeypatch):
    """Given normals replace the PCA normals of the first iteration (of every iteration with
    keep_normals), as on the points route."""
    points = _folded(150, seed=2)
    flagged = np.arange(150) % 3 == 0
    up = np.tile([0.0, 0.0, 1.0], (150, 1))
    clock = Clock(None, 0, 1)
    monkeypatch.setitem(edges.EDGES, "iterations", 1)
    kept = edges.sharpen(points, up, flagged, up, True, 16, 0.05, clock)
    estimated = edges.sharpen(points, up, flagged, None, False, 16, 0.05, clock)
    assert not np.array_equal(kept[0], estimated[0])
    monkeypatch.setitem(edges.EDGES, "iterations", 2)
    first = edges.sharpen(points, up, flagged, up, False, 16, 0.05, clock)
    always = edges.sharpen(points, up, flagged, up, True, 16, 0.05, clock)
    assert not np.array_equal(first[0], always[0])


@pytest.mark.parametrize("ratio, k", [(0.01, 48), (0.1, 48), (0.16, 96), (0.33, 128),
                                      (0.9, 128), (0.22, 109)])
def test_the_lists_grow_with_the_noise(ratio, k):
    """Anchored as ``EDGES["k"]`` says, log-log in between (0.22: between 96 at 0.16 and 128
    at 0.33)."""
    assert edges.list_length({"ratio": ratio}) == k
    probe = {"ratio": ratio, "probe_radius": 2.0, "probe_k": 32}
    assert edges.reach(probe, k) == pytest.approx(edges.EDGES["reach"] * 2.0 * np.sqrt(k / 32))


def test_unflagged_points_stay_where_the_cells_put_them(monkeypatch):
    """And the default's edges route moves its flagged points within their lists."""
    from pssd_fast.routes import plan

    monkeypatch.setitem(plan.PRESETS["default"], "scales_up_to", 0)
    cloud = datasets.cad_part(n_points=30_000, noise=0.0005, seed=7)
    light = pssd_fast.denoise(cloud.points)
    assert light.stats["plan"]["route"] == "edges"
    cells = pssd_fast.denoise(cloud.points, preset="fast")
    moved = np.flatnonzero((light.points != cells.points).any(axis=1))
    assert len(moved) == light.stats["plan"]["edges"]["flagged"]
    # The flagged points are the ones near the features: most of them within 1% of an edge.
    assert np.mean(cloud.edge_distance[moved] < 0.01 * cloud.diagonal) > 0.5
    # Two steps, each within its list of 48 (about 2.5 spacings here).
    assert light.displacement[moved].max() < 0.02 * cloud.diagonal
    near = cloud.edge_distance < 0.01 * cloud.diagonal
    error = cloud.surface_distance(light.points)
    assert error[near].mean() < cloud.surface_distance(cells.points)[near].mean()
