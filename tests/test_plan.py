"""The run plan: one decision of the route for denoise and the tiled runs
(docs/ALGORITHM.md, "Routes")."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets
from pssd_fast.routes import plan
from pssd_fast.routes import coarse


@pytest.fixture(scope="module")
def quiet():
    """Noise well below the spacing: the default iterates on the points."""
    return np.array(datasets.make("cad_part", n_points=3000, noise=0.001, seed=4).points)


@pytest.mark.parametrize("options, route, k, rebuild", [
    ({}, "walks", None, True),
    ({"select_scales": False}, "points", None, True),
    ({"select_scales": False, "rebuild_graph": False}, "points", None, False),
    ({"k": 20, "select_scales": False}, "points", 20, True),
    ({"preset": "fast"}, "cells", None, None),
    ({"preset": "paper"}, "points", 25, True),
    ({"method": "bilateral"}, "points", None, True),
])
def test_the_plan_says_which_route_the_run_took(quiet, options, route, k, rebuild):
    result = pssd_fast.denoise(quiet, iterations=1, **options)
    taken = result.stats["plan"]
    assert taken["route"] == route
    assert taken["k"] == result.stats["k"] and (k is None or taken["k"] == k)
    assert taken["rebuild_graph"] == result.stats["rebuild_graph"]
    assert rebuild is None or taken["rebuild_graph"] == rebuild
    assert taken["select_scales"] == result.stats["params"].get("select_scales")
    assert (result.stats["scales"] is not None) == (route == "walks")
    assert (result.stats["auto_k"] is not None) == ("k" not in options
                                                     and options.get("preset") != "paper")
    if route == "cells":
        assert result.stats["auto_k"]["coarse"] is not None


def test_make_follows_the_callers_choices(quiet):
    """A given k skips the probe; a given rebuild_graph or select_scales overrides the
    preset's; a layout that finds no cells leaves the points route."""
    points = quiet - quiet.mean(axis=0)
    laid = []

    def layout(noise, cells):
        laid.append((noise, cells))
        return None

    found = plan.make(points, None, "fast", distinct=len(points), layout=layout,
                      rebuild_graph=True, select_scales=False)
    assert laid and found.route == "points" and found.rebuild_graph
    assert found.k == plan.PRESETS["fast"]["without_cells_k"] and found.layout is None
    given = plan.make(points, None, "default", distinct=len(points), layout=layout, k=30,
                      select_scales=True, sigma_n=0.05)
    assert given.probe is None and given.k == 30 and given.route == "walks"
    assert given.walks is not None and given.describe() == {
        "route": "walks", "k": 30, "rebuild_graph": True, "select_scales": True,
        "iterations": plan.PRESETS["default"]["iterations"], "cells": None, "edges": None}
    baseline = plan.make(points, None, "default", distinct=len(points), layout=layout,
                         aware_pipeline=False)
    assert baseline.route == "points" and baseline.select_scales is None
    assert laid == [(laid[0][0], "fast")]  # the baselines lay out no cells


@pytest.mark.parametrize("noise, light", [(0.0005, True), (0.03, False)])
def test_the_default_takes_the_edges_route_where_the_noise_is_low(monkeypatch, noise, light):
    """Above ``scales_up_to`` points (0 here): fast's probe, then fast's cells and the edges
    pass up to ``LIGHT["up_to"]``; the preset's own plan above."""
    monkeypatch.setitem(plan.PRESETS["default"], "scales_up_to", 0)
    points = datasets.cad_part(n_points=15_000, noise=noise, seed=2).points
    result = pssd_fast.denoise(points)
    taken = result.stats["plan"]
    assert (taken["route"] == "edges") == light and (taken["cells"] == "fast") == light
    assert result.stats["auto_k"]["probe_k"] == (32 if light else 96)
    assert taken["iterations"] == result.stats["n_iterations"] == (2 if light else 4)
    if light:
        assert result.stats["auto_k"]["ratio"] <= plan.LIGHT["up_to"]
        assert 0 < taken["edges"]["flagged"] < taken["edges"]["zone"] < len(points)
    else:
        assert taken["edges"] is None


@pytest.fixture(scope="module")
def edgy():
    """Where the default takes the edges route once it is allowed to (above 0 points)."""
    return datasets.cad_part(n_points=30_000, noise=0.0005, seed=2).points


@pytest.mark.parametrize("options, route", [
    ({"k": 30}, "points"), ({"select_scales": True}, "walks"), ({"method": "mls"}, "points"),
    ({"preset": "paper"}, "points"), ({"iterations": 3}, "edges")])
def test_the_edges_route_leaves_the_callers_choices(monkeypatch, edgy, options, route):
    monkeypatch.setitem(plan.PRESETS["default"], "scales_up_to", 0)
    result = pssd_fast.denoise(edgy, **{"iterations": 1, **options})
    assert result.stats["plan"]["route"] == route
    assert result.stats["n_iterations"] == result.stats["plan"]["iterations"] == \
        options.get("iterations", 1)


@pytest.mark.parametrize("noise, route, light", [
    pytest.param(0.001, "points", False, marks=pytest.mark.slow),  # halos: tests/test_tiled.py
    (0.02, "cells", False), (0.0005, "edges", True)])
def test_tiled_runs_follow_the_same_plan(monkeypatch, tmp_path, noise, route, light):
    pytest.importorskip("dask")
    from pssd_fast import tiled

    monkeypatch.setitem(coarse.COARSE["default"], "min_ratio", 0.3)
    if light:
        monkeypatch.setitem(plan.PRESETS["default"], "scales_up_to", 0)
    points = np.array(datasets.make("cad_part", n_points=30_000, noise=noise, seed=6).points)
    whole = pssd_fast.denoise(points, select_scales=False, iterations=1)
    tiles = tiled.denoise(points, select_scales=False, iterations=1, tile_points=12_000,
                          client="sync")
    assert whole.stats["plan"]["route"] == route
    assert tiles.stats["plan"] == whole.stats["plan"]
    np.testing.assert_array_equal(tiles.points, whole.points)
    np.save(tmp_path / "in.npy", points)
    stats = tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", select_scales=False,
                               iterations=1, tile_points=12_000, client="sync")
    assert stats["plan"] == whole.stats["plan"]
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), whole.points)
