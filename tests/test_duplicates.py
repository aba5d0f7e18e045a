"""Duplicate points are denoised as one: they neither distort the noise estimate, the spacing,
the region radius or the cells, nor come apart (docs/DECISIONS.md, "Duplicates")."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets, duplicates

from .test_support import RUNS


def reference_ordered(points, tolerance=0.0):
    """:func:`pssd_fast.duplicates.ordered` by loops: the rows grouped by position (their
    coordinates, or with ``tolerance`` their cube ``floor((p - low) / tolerance)``), each
    group's first row standing for it, the groups along the Morton curve of their positions
    (the row, or its cube's low corner, in the grid of ``2**21 - 1`` cells along the longest
    side), ties in the order of their first rows."""
    from . import reference

    low, high = points.min(axis=0), points.max(axis=0)
    extent = (high - low).max()
    scale = (2**21 - 1) / extent if extent > 0 else 0.0

    def key(p):
        return tuple(p) if tolerance == 0 else tuple(np.floor((p - low) / tolerance))

    def code(key):
        corner = (np.array(key) if tolerance == 0
                  else np.minimum(low + np.array(key) * tolerance, high))
        return reference.morton_code([int(c) for c in np.floor((corner - low) * scale)])

    keys = [key(p) for p in points]
    first = {}
    for row, found in enumerate(keys):
        first.setdefault(found, row)
    order = sorted(first.values(), key=lambda row: (code(keys[row]), row))
    position = {keys[row]: i for i, row in enumerate(order)}
    return np.array(order), np.array([position[found] for found in keys])


@pytest.mark.parametrize("case", ["distinct", "exact", "near", "all one", "signed zeros",
                                  "cubes", "cubes of copies"])
def test_ordered_matches_the_reference(case):
    rng = np.random.default_rng(4)
    points = rng.normal(size=(300, 3))
    tolerance = 0.0
    if case in ("exact", "cubes of copies"):
        points[rng.integers(0, 300, 120)] = points[rng.integers(0, 300, 120)]
    elif case == "near":  # a few billionths of the extent apart: distinct positions
        points[:100] = points[100:200] + rng.normal(0, 1e-9, (100, 3))
    elif case == "all one":
        points[:] = points[0]
    elif case == "signed zeros":  # equal coordinates, one position
        points[:10] = 0.0
        points[5:10, 1] = -0.0
    if case.startswith("cubes"):
        tolerance = 0.3
    order, groups = duplicates.ordered(points, tolerance)
    want_order, want_groups = reference_ordered(points, tolerance)
    np.testing.assert_array_equal(order, want_order)
    if case in ("distinct", "near"):
        assert groups is None and np.array_equal(order, pssd_fast.morton_order(points))
    else:
        np.testing.assert_array_equal(groups, want_groups)
        assert len(order) < len(points)


def test_rows_a_cell_of_the_ordering_apart_stay_distinct():
    """Rows a fraction of a cell of the ordering's Morton grid apart, one cell, two cells, and
    one ulp apart (in one cell) are each their own position; exact copies of them merge."""
    rng = np.random.default_rng(7)
    points = rng.uniform(0, 1000, (200, 3))
    cell = np.ptp(points, axis=0).max() / (2**21 - 1)
    base = points[:20]
    steps = [np.nextafter(base, np.inf)] + [base + f * cell for f in (0.25, 0.5, 1.0, 2.0)]
    close = np.concatenate([points, *steps])
    order, groups = duplicates.ordered(close)
    assert groups is None and order.shape[0] == close.shape[0]
    copied = np.concatenate([close, close[::3]])
    order, groups = duplicates.ordered(copied)
    assert order.shape[0] == close.shape[0]
    np.testing.assert_array_equal(groups[close.shape[0]:], groups[:close.shape[0]:3])


def _with_copies(points, seed=0, near=0.0):
    """``points`` with some rows repeated (up to four times; with ``near``, a fifth of the
    copies ``near`` times the extent away, along a random direction), shuffled; and for each
    row of the result, the row of ``points`` it copies."""
    rng = np.random.default_rng(seed)
    source = np.concatenate([np.arange(len(points)), rng.integers(0, len(points), len(points))])
    source = source[rng.permutation(len(source))]
    copies = points[source].copy()
    if near:
        low, high = points.min(axis=0), points.max(axis=0)
        # Off the bounding box's faces, so that the copies' box is the points'.
        inside = np.all((points > low + 1e-6) & (points < high - 1e-6), axis=1)
        moved = (rng.random(len(source)) < 0.2) & inside[source]
        step = rng.normal(size=(moved.sum(), 3))
        step *= near * np.ptp(points, axis=0).max() / np.linalg.norm(step, axis=1)[:, None]
        copies[moved] += step
    return copies, source


@pytest.mark.parametrize("run", sorted(RUNS))
def test_copies_are_denoised_as_one_point(run):
    """A cloud with every point copied up to four times gives each copy the result of the
    cloud without copies: the same noise, k, cells and positions, bit for bit."""
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
    # coordinates).
    np.testing.assert_allclose(together.displacement,
                               np.linalg.norm(together.points - copies, axis=1), rtol=1e-12,
                               atol=4 * np.finfo(float).eps * np.abs(copies).max())


def test_copies_stay_together_in_tiled_runs():
    pytest.importorskip("dask")
    from pssd_fast import tiled

    points = np.array(datasets.make("cad_part", n_points=12_000, noise=0.0005, seed=3).points)
    copies, source = _with_copies(points, seed=1)
    whole = pssd_fast.denoise(copies)
    tiles = tiled.denoise(copies, tile_points=9_000, client="sync")
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


@pytest.mark.parametrize("ext, n, noise", [(".npy", 15_000, 0.001), (".npy", 30_000, 0.02),
                                           (".las", 30_000, 0.02)])
def test_copies_stay_together_out_of_core(tmp_path, monkeypatch, ext, n, noise):
    """denoise_file sets the copies aside while it bins the file and gives each its first
    row's result as it writes the output: the in-core file, bit for bit, with cells of about
    one point and of several, with blocks of rows so small that copies and their first rows
    fall in different blocks."""
    pytest.importorskip("dask")
    from pssd_fast import io, tiled
    from pssd_fast.tiled import ondisk

    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 6_000)
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
        copies = io.read(source).points  # as quantised
    whole = pssd_fast.denoise(copies, extras=True)
    fields = ondisk.RESULT_FIELDS if ext == ".las" else ()
    stats = tiled.denoise_file(source, out, tile_points=3_000, client="sync", fields=fields,
                               extras=bool(fields))
    assert stats["tiles"]["count"] >= 4
    assert stats["duplicates"] == whole.stats["duplicates"] > 0
    assert stats["n_points"] == len(copies)
    # Every row's move, the copies' included, before a LAS file rounds the coordinates.
    moved = np.linalg.norm(whole.points - copies, axis=1)
    assert stats["displacement"]["max"] == pytest.approx(moved.max(), rel=1e-12)
    assert stats["displacement"]["mean"] == pytest.approx(moved.mean(), rel=1e-12)
    if ext == ".npy":
        np.testing.assert_array_equal(np.load(out), whole.points)
        return
    read = io.read(source)
    io.write(want, read, points=whole.points, normals=whole.normals, fields={
        name: getattr(whole, name).astype(np.float32)
        for name in ("likelihood", "feature_intensity", "displacement")})
    got, expected = (laspy.read(str(path)) for path in (out, want))
    np.testing.assert_array_equal(got.points.array, expected.points.array)


def _corridor(offset=(0.0, 0.0, 0.0), seed=0):
    """A corridor survey: 10,000 ground points on a strip 2 km long and 2 m wide, and 1,000
    distinct points within 1 cm x 1 cm of its middle (a scanner's density near the sensor);
    ``offset`` added."""
    rng = np.random.default_rng(seed)
    strip = np.column_stack([rng.uniform(0, 2000, 10_000), rng.uniform(0, 2, 10_000),
                             rng.normal(0, 0.01, 10_000)])
    patch = np.column_stack([1000 + rng.uniform(0, 0.01, 1_000), 1 + rng.uniform(0, 0.01, 1_000),
                             rng.normal(0, 2e-4, 1_000)])
    return np.concatenate([strip, patch]) + offset


#: One iteration: the corridor's runs, kept short.
SHORT = {"iterations": 1}


def test_the_corridor_keeps_every_distinct_point():
    """The patch's 1,000 points fall in 236 cells of the ordering's Morton grid (2 km / 2**21,
    about 1 mm): merged by cell, as before, they came back as 236 positions. Each keeps its own
    result."""
    from pssd_fast.graph import morton_cells

    points = _corridor()
    assert np.unique(morton_cells(points)[-1_000:]).shape[0] < 300  # the case holds
    whole = pssd_fast.denoise(points, **SHORT)
    assert whole.stats["duplicates"] == 0
    assert np.unique(whole.points[-1_000:], axis=0).shape[0] == 1_000


def test_the_corridor_keeps_every_distinct_point_in_tiled_runs(tmp_path, monkeypatch):
    """Each of the patch's points keeps the in-core result in tiled runs in memory and on
    disk, bit for bit."""
    pytest.importorskip("dask")
    from pssd_fast import tiled
    from pssd_fast.tiled import ondisk

    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 3_000)
    points = _corridor()
    whole = pssd_fast.denoise(points, **SHORT)
    tiles = tiled.denoise(points, tile_points=4_000, client="sync", **SHORT)
    assert tiles.stats["duplicates"] == 0 and tiles.stats["tiles"]["count"] >= 3
    np.testing.assert_array_equal(tiles.points, whole.points)
    np.save(tmp_path / "in.npy", points)
    stats = tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", tile_points=4_000,
                               client="sync", **SHORT)
    assert stats["duplicates"] == 0 and stats["tiles"]["count"] >= 3
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), whole.points)


def test_utm_offsets_merge_copies_not_neighbours_an_ulp_apart():
    """At UTM coordinates (500 km east, 5,000 km north, an ulp of 1 nm) the exact copies
    merge and move with their first row; rows one ulp away stay their own positions."""
    points = _corridor(offset=(500_000.0, 5_000_000.0, 100.0))
    rng = np.random.default_rng(1)
    rows = rng.choice(points.shape[0], 300, replace=False)
    n = points.shape[0]
    cloud = np.concatenate([points, points[rows], np.nextafter(points[rows[:100]], np.inf)])
    order, groups = duplicates.ordered(cloud)
    assert order.shape[0] == n + 100
    np.testing.assert_array_equal(groups[n:n + 300], groups[rows])
    assert not np.isin(groups[n + 300:], groups[:n]).any()
    result = pssd_fast.denoise(cloud, **SHORT)
    assert result.stats["duplicates"] == 300
    np.testing.assert_array_equal(result.points[n:n + 300], result.points[rows])
    np.testing.assert_array_equal(result.normals[n:n + 300], result.normals[rows])
    np.testing.assert_allclose(result.displacement,
                               np.linalg.norm(result.points - cloud, axis=1), rtol=1e-12,
                               atol=4 * np.finfo(float).eps * np.abs(cloud).max())


def _cube_copies():
    """The generated part with copies 1e-10 of its extent apart, and a tolerance of 1e-7 of
    it."""
    points = np.array(datasets.make("cad_part", n_points=4000, noise=0.005, seed=2).points)
    copies, _ = _with_copies(points, seed=3, near=1e-10)
    return copies, 1e-7 * np.ptp(copies, axis=0).max()


def test_a_tolerance_merges_the_rows_of_one_cube():
    """``duplicate_tolerance=t``: the rows whose ``floor((p - low) / t)`` agree are one
    point."""
    copies, tolerance = _cube_copies()
    cube = np.unique(np.floor((copies - copies.min(axis=0)) / tolerance), axis=0,
                     return_inverse=True)[1].ravel()
    exact = copies.shape[0] - np.unique(copies, axis=0).shape[0]
    whole = pssd_fast.denoise(copies, duplicate_tolerance=tolerance, **SHORT)
    assert whole.stats["duplicates"] == copies.shape[0] - (cube.max() + 1) > exact + 500
    # Every row of a cube ends where its first row does, each with its own displacement.
    assert np.unique(np.column_stack([cube, whole.points]), axis=0).shape[0] == cube.max() + 1
    np.testing.assert_allclose(whole.displacement,
                               np.linalg.norm(whole.points - copies, axis=1), rtol=1e-12,
                               atol=4 * np.finfo(float).eps * np.abs(copies).max())


def test_a_tolerance_merges_the_rows_of_one_cube_in_tiled_runs(tmp_path, monkeypatch):
    """The in-core result of the cube's rows in tiled runs in memory and on disk, bit for
    bit."""
    pytest.importorskip("dask")
    from pssd_fast import tiled
    from pssd_fast.tiled import ondisk

    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 3_000)
    copies, tolerance = _cube_copies()
    whole = pssd_fast.denoise(copies, duplicate_tolerance=tolerance, **SHORT)
    tiles = tiled.denoise(copies, tile_points=3_000, client="sync", duplicate_tolerance=tolerance,
                          **SHORT)
    np.testing.assert_array_equal(tiles.points, whole.points)
    np.save(tmp_path / "in.npy", copies)
    stats = tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", tile_points=3_000,
                               client="sync", duplicate_tolerance=tolerance, **SHORT)
    assert stats["duplicates"] == whole.stats["duplicates"]
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), whole.points)


@pytest.mark.parametrize("value, error", [(-1e-3, ValueError), (float("nan"), ValueError),
                                          (float("inf"), ValueError), ("0.1", TypeError),
                                          (True, TypeError), (1e-320, ValueError)])
def test_bad_tolerances_are_named(value, error):
    points = np.random.default_rng(0).normal(size=(100, 3))
    with pytest.raises(error, match="duplicate_tolerance"):
        pssd_fast.denoise(points, duplicate_tolerance=value)


@pytest.mark.parametrize("value, error", [(-1e-3, ValueError), (float("nan"), ValueError),
                                          (float("inf"), ValueError), ("0.1", TypeError),
                                          (True, TypeError), (1e-320, ValueError)])
def test_bad_tolerances_are_named_by_tiled_runs(tmp_path, value, error):
    pytest.importorskip("dask")
    from pssd_fast import tiled

    points = np.random.default_rng(0).normal(size=(100, 3))
    np.save(tmp_path / "in.npy", points)
    for run in (lambda: tiled.denoise(points, duplicate_tolerance=value),
                lambda: tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy",
                                           duplicate_tolerance=value)):
        with pytest.raises(error, match="duplicate_tolerance"):
            run()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.npy"]
