"""Duplicate points are denoised as one: they neither distort the noise estimate, the spacing,
the region radius or the cells, nor come apart (docs/DECISIONS.md, "Duplicates")."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets, duplicates

from .test_support import RUNS


def reference_ordered(points):
    """:func:`pssd_fast.duplicates.ordered` by loops: the rows grouped by their cell of the
    Morton grid (``2**21 - 1`` cells along the longest side), each group's first row standing
    for it, the groups along the Morton curve."""
    from . import reference

    low = points.min(axis=0)
    extent = (points.max(axis=0) - low).max()
    scale = (2**21 - 1) / extent if extent > 0 else 0.0
    cells = [tuple(int(c) for c in np.floor((p - low) * scale)) for p in points]
    codes = [reference.morton_code(c) for c in cells]
    first = {}
    for row, code in enumerate(codes):
        first.setdefault(code, row)
    order = [first[code] for code in sorted(first)]
    position = {code: i for i, code in enumerate(sorted(first))}
    return np.array(order), np.array([position[code] for code in codes])


@pytest.mark.parametrize("case", ["distinct", "exact", "near", "all one"])
def test_ordered_matches_the_reference(case):
    rng = np.random.default_rng(4)
    points = rng.normal(size=(300, 3))
    if case == "exact":
        points[rng.integers(0, 300, 120)] = points[rng.integers(0, 300, 120)]
    elif case == "near":  # copies a few billionths of the extent away
        points[:100] = points[100:200] + rng.normal(0, 1e-9, (100, 3))
    elif case == "all one":
        points[:] = points[0]
    order, groups = duplicates.ordered(points)
    want_order, want_groups = reference_ordered(points)
    np.testing.assert_array_equal(order, want_order)
    if case == "distinct":
        assert groups is None and np.array_equal(order, pssd_fast.morton_order(points))
    else:
        np.testing.assert_array_equal(groups, want_groups)
        assert len(order) < len(points)


def _with_copies(points, seed=0):
    """``points`` with some rows repeated (up to four times, a fifth of the copies 1e-13 of
    the extent away: within one cell of the Morton grid), shuffled; and for each row of the
    result, the row of ``points`` it copies."""
    rng = np.random.default_rng(seed)
    source = np.concatenate([np.arange(len(points)), rng.integers(0, len(points), len(points))])
    source = source[rng.permutation(len(source))]
    copies = points[source].copy()
    low, high = points.min(axis=0), points.max(axis=0)
    # Off the bounding box's faces, so that the copies' box (and so the grid) is the points'.
    inside = np.all((points > low + 1e-6) & (points < high - 1e-6), axis=1)
    near = (rng.random(len(source)) < 0.2) & inside[source]
    copies[near] += rng.normal(0, 1e-13, (near.sum(), 3)) * np.ptp(points, axis=0).max()
    return copies, source


@pytest.mark.parametrize("run", sorted(RUNS))
def test_copies_are_denoised_as_one_point(run):
    """A cloud with every point copied up to four times gives each copy the result of the
    cloud without copies: the same noise, k, cells and positions, bit for bit. (The first
    copy of each point in the shuffled cloud stands for it, so the copies without jitter keep
    the distinct cloud's exact result.)"""
    cloud = datasets.make("cad_part", n_points=6000, noise=0.005, seed=2)
    points = np.array(cloud.points)
    copies, source = _with_copies(points)
    # The distinct cloud as the copies' run sees it: each point's first copy.
    first = np.unique(source, return_index=True)[1]
    distinct = copies[first]
    alone = pssd_fast.denoise(distinct, **RUNS[run])
    together = pssd_fast.denoise(copies, **RUNS[run])
    assert together.stats["duplicates"] == len(copies) - len(points)
    assert together.stats["k"] == alone.stats["k"]
    assert together.stats["noise"] == alone.stats["noise"]
    rank = np.empty(len(points), np.int64)
    rank[source[first]] = np.arange(len(points))
    for name in ("points", "normals", "likelihood", "feature_intensity", "held"):
        got, want = getattr(together, name), getattr(alone, name)
        if want is None:
            assert got is None
            continue
        np.testing.assert_array_equal(got, want[rank[source]], err_msg=name)
    # Each copy's displacement is from its own input position (to the rounding of the
    # coordinates: near copies move by a few millionths).
    np.testing.assert_allclose(together.displacement,
                               np.linalg.norm(together.points - copies, axis=1), rtol=1e-12,
                               atol=4 * np.finfo(float).eps * np.abs(copies).max())


def test_copies_stay_together_in_tiled_runs():
    pytest.importorskip("dask")
    from pssd_fast import tiled

    points = np.array(datasets.make("cad_part", n_points=12_000, noise=0.0005, seed=3).points)
    copies, source = _with_copies(points, seed=1)
    # At k: the walks of select_scales (these 12,000 distinct points) tile in test_tiled.py.
    whole = pssd_fast.denoise(copies, select_scales=False)
    tiles = tiled.denoise(copies, tile_points=9_000, client="sync", select_scales=False)
    np.testing.assert_array_equal(tiles.points, whole.points)
    assert tiles.stats["duplicates"] == whole.stats["duplicates"] == len(points)
    # Every copy of a point ends where the others do.
    pairs = np.unique(np.column_stack([source, whole.points]), axis=0)
    assert len(pairs) == len(points)


def test_too_few_distinct_positions_are_refused():
    points = np.repeat(np.random.default_rng(0).normal(size=(8, 3)), 5, axis=0)
    with pytest.raises(ValueError, match="40 points but only 8 distinct positions"):
        pssd_fast.denoise(points)
    with pytest.raises(ValueError, match="for k = 20"):
        pssd_fast.denoise(np.repeat(points[:8], 4, axis=0)[:32], k=20)


@pytest.mark.parametrize("ext, n, noise, route", [(".npy", 15_000, 0.001, "halo"),
                                                  (".npy", 30_000, 0.02, "cells"),
                                                  (".las", 30_000, 0.02, "cells")])
def test_copies_stay_together_out_of_core(tmp_path, monkeypatch, ext, n, noise, route):
    """denoise_file sets the copies aside while it bins the file and gives each its first
    row's result as it writes the output: the in-core file, bit for bit, on both routes, with
    blocks of rows so small that copies and their first rows fall in different blocks."""
    pytest.importorskip("dask")
    from pssd_fast import io, tiled
    from pssd_fast.tiled import ondisk
    from pssd_fast.routes import coarse

    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 6_000)
    monkeypatch.setitem(coarse.COARSE["default"], "min_ratio", 0.3)
    points = np.array(datasets.make("cad_part", n_points=n, noise=noise, seed=6).points)
    copies, _ = _with_copies(points * 100 + [1000.0, 2000.0, 30.0], seed=2)
    source, out, want = (tmp_path / f"{name}{ext}" for name in ("in", "out", "want"))
    if ext == ".npy":
        np.save(source, copies)
    else:
        laspy = pytest.importorskip("laspy")
        header = laspy.LasHeader(point_format=6, version="1.4")
        header.scales = [1e-4] * 3
        header.offsets = [1000.0, 2000.0, 30.0]
        las = laspy.LasData(header)
        las.x, las.y, las.z = copies.T
        las.intensity = np.arange(len(copies)) % 65535
        las.write(str(source))
        copies = io.read(source).points  # as quantised: the copies 1e-13 apart are exact
    whole = pssd_fast.denoise(copies, select_scales=False)
    stats = tiled.denoise_file(source, out, tile_points=5_000, client="sync",
                               select_scales=False)
    assert stats["tiles"]["route"] == route and stats["tiles"]["count"] >= 4
    assert stats["duplicates"] == whole.stats["duplicates"] > 0
    assert stats["n_points"] == len(copies)
    if ext == ".npy":
        np.testing.assert_array_equal(np.load(out), whole.points)
        return
    read = io.read(source)
    io.write(want, read, points=whole.points, normals=whole.normals, fields={
        name: getattr(whole, name).astype(np.float32)
        for name in ("likelihood", "feature_intensity", "displacement")})
    got, expected = (laspy.read(str(path)) for path in (out, want))
    np.testing.assert_array_equal(got.points.array, expected.points.array)
