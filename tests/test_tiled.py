"""Tiled runs on Dask give the in-core result, bit for bit."""
import os

import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets, tiled
from pssd_fast.tiled import ondisk
from pssd_fast.denoise import PRESETS

pytest.importorskip("dask")

FIELDS = ("points", "normals", "likelihood", "feature_intensity", "displacement")


@pytest.fixture(scope="module", autouse=True)
def coarse_default():
    """The default's coarse-to-fine route from the probe ratio of these small clouds on (it
    takes it from 0.5, which a probe of 200,000 points hardly reaches; only the calling
    process reads the setting), and its own routes, not the light one, unless a test asks
    for it (:func:`light`)."""
    from pssd_fast.routes import coarse

    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(coarse.COARSE["default"], "min_ratio", 0.3)
        patch.setitem(PRESETS["default"], "light", False)
        yield


@pytest.fixture(scope="module")
def noisy():
    """Noise several point spacings wide: both presets take the coarse-to-fine route."""
    return datasets.cad_part(n_points=100_000, noise=0.02, seed=5)


@pytest.fixture(scope="module")
def in_core(noisy):
    return {preset: pssd_fast.denoise(noisy.points, preset=preset)
            for preset in ("default", "fast")}


@pytest.fixture(autouse=True)
def fit_at_k(monkeypatch):
    """The default fits at ``k`` here, whatever the size, so that these tests of the tiles stay
    cheap; the walks of ``select_scales`` tile in the tests that ask for them (and in
    :func:`test_the_default_selects_scales_on_the_whole_cloud`)."""
    monkeypatch.setitem(PRESETS["default"], "scales_up_to", 0)


@pytest.fixture
def light(monkeypatch):
    """The default's light route on these small clouds (above ``scales_up_to``, 0 here)."""
    monkeypatch.setitem(PRESETS["default"], "light", True)


@pytest.mark.slow
def test_a_million_points_in_sixteen_tiles_give_the_in_core_result():
    """The issue's case, at the default's own threshold: the generated part at 0.5% noise."""
    from pssd_fast.routes import coarse

    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(coarse.COARSE["default"], "min_ratio", 0.5)
        points = datasets.cad_part(n_points=1_000_000, noise=0.005, seed=0).points
        expected = pssd_fast.denoise(points)
        got = tiled.denoise(points, tile_points=60_000)
    assert got.stats["tiles"]["count"] >= 16
    _assert_same(got, expected)


def _assert_same(got, expected):
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(got, field), getattr(expected, field),
                                      err_msg=field)
    np.testing.assert_array_equal(got.kept, expected.kept)
    for key in ("k", "noise", "rebuild_graph", "n_iterations"):
        assert got.stats[key] == expected.stats[key]
    assert got.stats["auto_k"]["coarse"] == expected.stats["auto_k"]["coarse"]


@pytest.mark.parametrize("preset", ["default", "fast"])
def test_threads_give_the_in_core_result(noisy, in_core, preset):
    got = tiled.denoise(noisy.points, preset=preset, tile_points=10_000)
    assert got.stats["tiles"]["count"] >= 8
    assert got.stats["tiles"]["most_points"] <= 10_000
    assert got.stats["tiles"]["scheduler"] == "threads"
    _assert_same(got, in_core[preset])


def test_tasks_at_once_share_the_cores(noisy, in_core, monkeypatch):
    """Dask's local schedulers run at most n_jobs threads in all, tasks at once times the
    threads of each, and say so in stats; the result stays the in-core one."""
    import contextlib
    import threading

    from pssd_fast._threads import resolve_n_jobs

    cores = resolve_n_jobs(2)
    lock, busy, most = threading.Lock(), [0], [0]
    real = tiled.runner.threads

    @contextlib.contextmanager
    def counted(n_jobs):
        with real(n_jobs) as n:
            if threading.current_thread() is threading.main_thread():
                yield n  # the run's own setting, around the tasks
                return
            with lock:
                busy[0] += n
                most[0] = max(most[0], busy[0])
            try:
                yield n
            finally:
                with lock:
                    busy[0] -= n

    monkeypatch.setattr(tiled.runner, "threads", counted)
    got = tiled.denoise(noisy.points, tile_points=10_000, n_jobs=2)
    assert 0 < most[0] <= cores
    assert got.stats["tiles"]["threads"] == {"tasks_at_once": cores, "threads_per_task": 1}
    _assert_same(got, in_core["default"])
    alone = tiled.denoise(noisy.points, tile_points=10_000, n_jobs=2, client="sync")
    assert alone.stats["tiles"]["threads"] == {"tasks_at_once": 1, "threads_per_task": cores}
    _assert_same(alone, in_core["default"])


@pytest.mark.slow  # a local cluster of processes: the killed-worker test below too
def test_a_local_cluster_of_two_processes_gives_the_in_core_result(noisy, in_core):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        got = tiled.denoise(noisy.points, tile_points=12_500, client=client)
        assert got.stats["tiles"]["scheduler"] == "distributed"
        assert got.stats["tiles"]["count"] >= 8
        _assert_same(got, in_core["default"])
        # Each worker runs one task at a time: it gives that task all its cores.
        shares = client.run(tiled.runner._worker_threads)
        assert set(shares.values()) == {len(os.sched_getaffinity(0))}
        assert got.stats["tiles"]["threads"] == {
            "tasks_at_once": 2, "threads_per_task": len(os.sched_getaffinity(0))}
        # The scheduler's address does as well as the client.
        by_address = tiled.denoise(noisy.points, tile_points=50_000,
                                   client=cluster.scheduler_address)
        _assert_same(by_address, in_core["default"])


def test_given_normals_and_float32_tile_alike():
    cloud = datasets.cad_part(n_points=30_000, noise=0.02, seed=6)
    points = cloud.points.astype(np.float32)
    expected = pssd_fast.denoise(points, -cloud.normals)
    got = tiled.denoise(points, -cloud.normals, tile_points=3_000, client="sync")
    assert got.points.dtype == np.float32 and got.stats["tiles"]["count"] >= 8
    _assert_same(got, expected)


def test_orientation_tiles_alike():
    cloud = datasets.cad_part(n_points=30_000, noise=0.02, seed=6)
    expected = pssd_fast.denoise(cloud.points, orient="up", preset="fast")
    _assert_same(tiled.denoise(cloud.points, orient="up", preset="fast", tile_points=5_000),
                 expected)


def test_progress_hears_of_every_tile(noisy):
    seen = []
    tiled.denoise(noisy.points[:40_000], preset="fast", tile_points=4_000,
                  progress=lambda *args: seen.append(args[2]))
    cells = [s for s in seen if s.startswith("tile_cells")]
    updates = [s for s in seen if s.startswith("tile_update")]
    assert len(cells) == len(updates) >= 8
    assert cells[-1] == f"tile_cells {len(cells)}/{len(cells)}"
    assert updates[-1] == f"tile_update {len(updates)}/{len(updates)}"


@pytest.fixture(scope="module")
def sparse():
    """Noise well under the point spacing: the default iterates on the points."""
    return datasets.cad_part(n_points=12_000, noise=0.002, seed=3).points


@pytest.fixture(scope="module")
def sparse_in_core(sparse):
    # At k as in the tiles (fit_at_k, which a module fixture's setup precedes).
    return pssd_fast.denoise(sparse, select_scales=False)


def test_a_cloud_iterated_on_its_points_tiles_with_halos(sparse, sparse_in_core):
    got = tiled.denoise(sparse, tile_points=1_500)
    assert got.stats["tiles"]["route"] == "halo" and got.stats["tiles"]["count"] >= 8
    _assert_same(got, sparse_in_core)
    assert got.stats["iterations"][0]["fit_degree"] == \
        sparse_in_core.stats["iterations"][0]["fit_degree"]


def test_halos_too_thin_are_widened_until_exact(sparse, sparse_in_core, monkeypatch):
    """A first width of a quarter list radius: every tile fails its check and runs again."""
    from pssd_fast.tiled import halo

    monkeypatch.setattr(halo, "FIRST_WIDTH", 0.25)
    seen = []
    got = tiled.denoise(sparse, tile_points=3_000, progress=lambda *a: seen.append(a[2]))
    assert sum(s.startswith("tile_step") for s in seen) > 4 * got.stats["tiles"]["count"]
    _assert_same(got, sparse_in_core)


def _shorten_scales(patch):
    """The walks' long lists shortened to 1.5 k, and the first halo width to a quarter list
    radius, so that the tiles fail their checks, run again, and stay cheap."""
    from pssd_fast.tiled import halo
    from pssd_fast.routes import scales

    patch.setitem(scales.SCALES, "factors", (0.5, 1.0, 1.5))
    patch.setattr(halo, "FIRST_WIDTH", 0.25)


@pytest.fixture(scope="module")
def short_scales_in_core():
    points = datasets.cad_part(n_points=10_000, noise=0.002, seed=3).points
    with pytest.MonkeyPatch.context() as patch:
        _shorten_scales(patch)
        return points, pssd_fast.denoise(points, select_scales=True, iterations=2)


@pytest.fixture
def short_scales(monkeypatch, short_scales_in_core):
    """The points and their in-core result with the walks of :func:`_shorten_scales`, which
    hold during the test."""
    _shorten_scales(monkeypatch)
    return short_scales_in_core


def _same_walks(stats, expected):
    assert [r["scales"] for r in stats["iterations"]] == \
        [r["scales"] for r in expected.stats["iterations"]]
    assert {**stats["scales"], "seconds": 0} == {**expected.stats["scales"], "seconds": 0}
    assert stats["params"]["select_scales"] is True


def test_halos_cover_the_lists_of_selected_scales(short_scales):
    """select_scales: the plan is made before the tiles and each task's halo covers the walks'
    long lists."""
    points, expected = short_scales
    seen = []
    got = tiled.denoise(points, tile_points=1_250, select_scales=True, iterations=2,
                        client="sync", progress=lambda *a: seen.append(a[2]))
    assert got.stats["tiles"]["route"] == "halo"
    assert sum(s.startswith("tile_step") for s in seen) > 2 * 2 * got.stats["tiles"]["count"]
    _assert_same(got, expected)
    _same_walks(got.stats, expected)


@pytest.mark.slow
@pytest.mark.usefixtures("small_chunks")
def test_a_file_tiled_out_of_core_selects_scales_as_in_core(tmp_path, short_scales):
    points, expected = short_scales
    source, out = tmp_path / "in.npy", tmp_path / "out.npy"
    np.save(source, points)
    stats = tiled.denoise_file(source, out, tile_points=1_250, select_scales=True,
                               iterations=2, client="sync")
    assert stats["tiles"]["route"] == "halo"
    np.testing.assert_array_equal(np.load(out), expected.points)
    _same_walks(stats, expected)


@pytest.mark.slow
def test_the_default_selects_scales_on_the_whole_cloud(short_scales, monkeypatch):
    """The size that turns the walks on is the cloud's, not a tile's."""
    points, expected = short_scales
    monkeypatch.setitem(PRESETS["default"], "scales_up_to", 10_000)
    got = tiled.denoise(points, tile_points=1_250, iterations=2)
    _assert_same(got, expected)
    _same_walks(got.stats, expected)
    # Each tile is below this limit, the cloud is not.
    monkeypatch.setitem(PRESETS["default"], "scales_up_to", 9_999)
    off = tiled.denoise(points, tile_points=1_250, iterations=1)
    assert off.stats["scales"] is None and off.stats["params"]["select_scales"] is False


def test_halos_take_given_normals():
    cloud = datasets.cad_part(n_points=12_000, noise=0.002, seed=6)
    expected = pssd_fast.denoise(cloud.points, -cloud.normals)
    got = tiled.denoise(cloud.points, -cloud.normals, tile_points=1_500, client="sync")
    assert got.stats["tiles"]["route"] == "halo"
    _assert_same(got, expected)


@pytest.mark.usefixtures("light")
@pytest.mark.parametrize("normals", [False, True])
def test_the_edges_route_tiles_as_in_core(normals):
    """The pass of the edges route reads the same zone, in the same order, in every tile
    layout."""
    cloud = datasets.cad_part(n_points=40_000, noise=0.0005, seed=4)
    given = -cloud.normals if normals else None
    expected = pssd_fast.denoise(cloud.points, given)
    assert expected.stats["plan"]["route"] == "edges"
    got = tiled.denoise(cloud.points, given, tile_points=5_000, client="sync")
    assert got.stats["tiles"]["count"] >= 8 and got.stats["plan"] == expected.stats["plan"]
    assert got.stats["held_points"] == expected.stats["held_points"]
    _assert_same(got, expected)


def test_halos_orient_each_normal_alone(sparse, sparse_in_core):
    got = tiled.denoise(sparse, tile_points=3_000, orient="up")
    np.testing.assert_array_equal(got.points, sparse_in_core.points)
    assert (got.normals[:, 2] >= 0).all()
    np.testing.assert_array_equal(np.abs(got.normals), np.abs(sparse_in_core.normals))


def test_fast_without_cells_is_refused(monkeypatch):
    from pssd_fast.routes import coarse

    monkeypatch.setattr(coarse, "layout", lambda *args: None)
    with pytest.raises(ValueError, match="use preset 'default'"):
        tiled.denoise(datasets.cad_part(n_points=5_000, noise=0.02, seed=1).points,
                      preset="fast")


@pytest.mark.parametrize("n", [1, 7, 128, 129, 1000, 123_457])
@pytest.mark.parametrize("block", [1, 100, 4096])
def test_the_mean_read_by_ranges_is_numpys(n, block):
    from pssd_fast.tiled.halo import pairwise_mean

    values = np.random.default_rng(n).random(n) ** 3 * 1e3
    assert pairwise_mean(lambda a, b: values[a:b], n, block) == float(np.mean(values))


@pytest.mark.parametrize("kwargs, error, match", [
    ({"tile_points": 0}, ValueError, "tile_points"),
    ({"client": 3}, TypeError, "client"),
    ({"preset": "paper"}, ValueError, "preset"),
    ({"sigma_n": -1.0}, ValueError, "sigma_n"),
    ({"select_scales": "yes"}, TypeError, "select_scales must be True, False or 'auto'"),
    ({"k": 30}, ValueError, "do not take k=30"),
    ({"method": "mls", "lam": 0.5}, ValueError, r"method='mls', lam=0\.5 \(use"),
    ({"rebuild_graph": True, "remove_outliers": True}, ValueError,
     "rebuild_graph=True, remove_outliers=True"),
    ({"classes": [2]}, ValueError, "classes and classification go together"),
    ({"classification": np.zeros(100, np.uint8), "classes": "some"}, ValueError,
     "class codes, 'each' or 'all'"),
    ({"classification": np.zeros(100, np.uint8), "classes": [2]}, ValueError,
     "no point is of class 2; the classes present are 0"),
    ({"classification": np.full(100, 5, np.uint8)}, ValueError, "no point is of a surface"),
    ({"classification": np.zeros(10, np.uint8), "classes": [2]}, ValueError, r"shape \(100,\)"),
    ({"classification": np.zeros(100), "classes": [2]}, TypeError, "integers"),
    ({"keep_normals": True}, ValueError, "keep_normals=True"),
    ({"shift_normals": False}, ValueError, "shift_normals=False"),
    ({"h": 0.1}, ValueError, "h=0.1"),
    ({"sigma": 0.1}, TypeError, "unknown parameter"),
])
def test_bad_arguments_are_named(kwargs, error, match):
    with pytest.raises(error, match=match):
        tiled.denoise(np.zeros((100, 3)), **kwargs)


def test_tiled_runs_take_denoise_s_parameters_at_their_defaults():
    """Every parameter of pssd_fast.denoise is one of the tiled runs', and its default (or
    "auto", as None) runs: the refusals above are the only ones."""
    import inspect

    ours = inspect.signature(pssd_fast.denoise).parameters
    # A file's points and normals are the file's.
    for func, own in ((tiled.denoise, {"points"}), (tiled.denoise_file, {"points", "normals"})):
        theirs = inspect.signature(func).parameters
        assert set(ours) - own <= set(theirs)
        assert all(theirs[name].default == p.default for name, p in ours.items()
                   if name not in own)
    points = datasets.cad_part(n_points=4000, noise=0.01, seed=1).points
    defaults = dict(method="robust", k="auto", lam=None, rebuild_graph=None,
                    remove_outliers=False, classification=None, classes=None, h="auto",
                    keep_normals=False, shift_normals=True, likelihood="exp", iterations=1)
    got = tiled.denoise(points, tile_points=2_000, client="sync", **defaults)
    assert np.array_equal(got.points, pssd_fast.denoise(points, iterations=1).points)


@pytest.fixture
def small_chunks(monkeypatch):
    """Chunks, buckets and tiles of a few thousand points: every pass crosses boundaries."""
    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 6_000)


@pytest.mark.usefixtures("small_chunks")
@pytest.mark.parametrize("preset, dtype, noise", [("default", np.float64, 0.02),
                                                  ("fast", np.float32, 0.02),
                                                  pytest.param("default", np.float32, 0.002,
                                                               marks=pytest.mark.slow)])
def test_a_file_tiled_out_of_core_gives_the_in_core_points(tmp_path, preset, dtype, noise):
    points = datasets.cad_part(n_points=60_000, noise=noise, seed=8).points.astype(dtype)
    source, out, scratch = tmp_path / "in.npy", tmp_path / "out.npy", tmp_path / "scratch"
    np.save(source, points)
    scratch.mkdir()
    expected = pssd_fast.denoise(points, preset=preset)
    stats = tiled.denoise_file(source, out, tile_points=5_000, preset=preset, client="sync",
                               scratch=scratch)
    got = np.load(out)
    assert got.dtype == dtype and stats["tiles"]["count"] >= 8
    np.testing.assert_array_equal(got, expected.points)
    assert stats["k"] == expected.stats["k"]
    coarse, in_core = stats["auto_k"]["coarse"], expected.stats["auto_k"]["coarse"]
    if in_core is not None:
        # The tiles' residual sums are added tile by tile: their mean may differ in the last bit.
        coarse, in_core = dict(coarse), dict(in_core)
        assert coarse.pop("mean_residual") == pytest.approx(in_core.pop("mean_residual"),
                                                            rel=1e-12)
    assert coarse == in_core
    assert list(scratch.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == [
        "in.npy", "out.npy", "scratch"]


@pytest.mark.usefixtures("small_chunks")
@pytest.mark.parametrize("ext, noise, route, normals", [
    (".las", 0.02, "cells", False), (".laz", 0.02, "cells", False),
    pytest.param(".las", 0.001, "halo", False, marks=pytest.mark.slow),
    (".las", 0.02, "cells", True),
    pytest.param(".laz", 0.001, "halo", True, marks=pytest.mark.slow),
    (".las", 0.0005, "edges", False),
    (".laz", 0.0005, "edges", True)])
def test_a_las_file_tiled_out_of_core_is_the_in_core_file(tmp_path, request, ext, noise,
                                                          route, normals):
    """Records, scale, offset, VLRs and EVLRs as read; the coordinates, normals, likelihood,
    feature intensity and displacement those of denoise, as the in-core writer stores them
    (``route``: the tiles', or the plan's edges route). A file with normals, by default: its
    normals updated and nothing added; without: every field asked for."""
    laspy = pytest.importorskip("laspy")
    from pssd_fast import io

    if route == "edges":
        request.getfixturevalue("light")

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = [0.0001, 0.0001, 0.0001]
    header.offsets = [500_000.0, 4_000_000.0, 300.0]
    header.vlrs.append(laspy.VLR("pssd_test", 7, "a VLR", b"kept"))
    from laspy.vlrs.vlrlist import VLRList

    header.evlrs = VLRList([laspy.VLR("pssd_test", 8, "an EVLR", b"kept too")])
    cloud = datasets.cad_part(n_points=40_000, noise=noise, seed=8)
    points = cloud.points * 100
    if normals:  # read as the given normals, of any length
        header.add_extra_dims([laspy.ExtraBytesParams(c, np.float32) for c in ("nx", "ny", "nz")])
    las = laspy.LasData(header)
    las.x, las.y, las.z = (points + [500_123.0, 4_000_456.0, 310.0]).T
    las.intensity = np.arange(len(points)) % 65535
    las.gps_time = np.linspace(0.0, 1e5, len(points))
    if normals:
        las.nx, las.ny, las.nz = (cloud.normals * 3.0).T
    source = tmp_path / f"scan{ext}"
    las.write(str(source))
    read = io.read(source)
    expected = tmp_path / f"in_core{ext}"
    assert (read.normals is not None) == normals
    result = pssd_fast.denoise(read.points, read.normals)
    fields = () if normals else ondisk.RESULT_FIELDS
    io.write(expected, read, points=result.points, normals=result.normals, fields={
        name: getattr(result, name).astype(np.float32)
        for name in ("likelihood", "feature_intensity", "displacement") if name in fields})
    stats = tiled.denoise_file(source, tmp_path / f"tiled{ext}", tile_points=5_000,
                               client="sync", **({} if normals else {"fields": fields}))
    assert stats["tiles"]["count"] >= 8
    assert route in (stats["tiles"]["route"], stats["plan"]["route"])
    assert stats["plan"] == result.stats["plan"]
    got, want, before = (laspy.read(str(tmp_path / name))
                         for name in (f"tiled{ext}", f"in_core{ext}", f"scan{ext}"))
    np.testing.assert_array_equal(got.points.array, want.points.array)
    for name in ("intensity", "gps_time"):
        np.testing.assert_array_equal(np.asarray(got[name]), np.asarray(before[name]))
    np.testing.assert_array_equal(got.header.scales, before.header.scales)
    np.testing.assert_array_equal(got.header.offsets, before.header.offsets)
    assert [v.record_data for v in got.header.vlrs if v.user_id == "pssd_test"] == [b"kept"]
    assert [type(v) for v in got.header.vlrs] == [type(v) for v in want.header.vlrs]
    assert [v.record_data for v in got.evlrs] == [b"kept too"]
    assert np.abs(np.asarray(got.X) - np.asarray(before.X)).mean() > 10  # moved


@pytest.mark.usefixtures("small_chunks")
def test_a_zarr_group_tiled_out_of_core_gives_the_in_core_points(tmp_path):
    zarr = pytest.importorskip("zarr")
    points = datasets.cad_part(n_points=40_000, noise=0.02, seed=4).points.astype(np.float32)
    group = zarr.open_group(str(tmp_path / "in.zarr"), mode="w")
    group.create_array("points", shape=points.shape, dtype=points.dtype, chunks=(4_096, 3))
    group["points"][:] = points
    (tmp_path / "out.zarr").mkdir()
    with pytest.raises(FileExistsError):
        tiled.denoise_file(tmp_path / "in.zarr", tmp_path / "out.zarr", tile_points=5_000)
    stats = tiled.denoise_file(tmp_path / "in.zarr", tmp_path / "out.zarr", tile_points=5_000,
                               overwrite=True)
    got = zarr.open_array(str(tmp_path / "out.zarr"), mode="r")
    assert stats["tiles"]["count"] >= 8 and got.chunks == (4_096, 3)
    np.testing.assert_array_equal(got[:], pssd_fast.denoise(points).points)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.zarr", "out.zarr"]


@pytest.mark.parametrize("n, noise, stage", [pytest.param(100_000, 0.02, "tile_update",
                                                          marks=pytest.mark.slow),
                                             pytest.param(40_000, 0.002, "tile_step",
                                                          marks=pytest.mark.slow),
                                             (40_000, 0.0005, "tile_edges")])
def test_a_file_on_a_local_cluster_survives_a_killed_worker(tmp_path, request, n, noise,
                                                            stage):
    """A worker killed while the tiles run: Dask runs its tasks again, the result stands
    (``tile_edges``: the edges route's tasks that write the pass's points into the parts)."""
    import signal

    distributed = pytest.importorskip("distributed")
    if stage == "tile_edges":
        request.getfixturevalue("light")
    points = datasets.cad_part(n_points=n, noise=noise, seed=9).points
    source, out = tmp_path / "in.npy", tmp_path / "out.npy"
    np.save(source, points)
    expected = pssd_fast.denoise(points)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        victim = next(iter(client.run(os.getpid).values()))
        killed = []

        def kill_once(iteration, iterations, seen, seconds):
            if seen.startswith(stage) and not killed:
                os.kill(victim, signal.SIGKILL)
                killed.append(seen)

        tiled.denoise_file(source, out, tile_points=5_000, client=client, progress=kill_once)
    assert killed
    np.testing.assert_array_equal(np.load(out), expected.points)


def test_a_failing_tile_leaves_no_output_and_no_scratch(tmp_path, monkeypatch):
    from pssd_fast.routes import coarse

    np.save(tmp_path / "in.npy", datasets.cad_part(n_points=30_000, noise=0.02, seed=8).points)

    def fail(*args):
        raise RuntimeError("a tile failed")

    monkeypatch.setattr(coarse, "onto_fits", fail)
    with pytest.raises(RuntimeError, match="a tile failed"):
        tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", tile_points=5_000,
                           client="sync")
    assert [p.name for p in tmp_path.iterdir()] == ["in.npy"]


@pytest.mark.parametrize("name, write, error, match", [
    ("in.xyz", None, ValueError, "reads .npy into .npy"),
    ("in.npy", np.array([[0.0, 0.0, np.nan]] * 50), ValueError, "row 0"),
    ("in.npy", np.zeros((50, 3), np.complex128), TypeError, "real numbers"),
    ("in.npy", np.zeros((50, 2)), ValueError, r"shape \(n, 3\)"),
])
def test_bad_files_are_named(tmp_path, name, write, error, match):
    source = tmp_path / name
    if write is not None:
        np.save(source, write)
    with pytest.raises(error, match=match):
        tiled.denoise_file(source, tmp_path / "out.npy")
    assert not (tmp_path / "out.npy").exists()


def test_formats_do_not_mix(tmp_path):
    np.save(tmp_path / "in.npy", np.zeros((50, 3)))
    with pytest.raises(ValueError, match=r"\.las/\.laz into \.las/\.laz"):
        tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.laz")


def test_a_truncated_file_is_named(tmp_path):
    source = tmp_path / "in.npy"
    np.save(source, np.zeros((50, 3)))
    source.write_bytes(source.read_bytes()[:-100])
    with pytest.raises(ValueError, match="truncated"):
        tiled.denoise_file(source, tmp_path / "out.npy")
    assert [p.name for p in tmp_path.iterdir()] == ["in.npy"]


def test_an_existing_output_is_kept_unless_overwritten(tmp_path):
    np.save(tmp_path / "in.npy", np.zeros((50, 3)))
    (tmp_path / "out.npy").write_bytes(b"keep")
    with pytest.raises(FileExistsError):
        tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy")
    with pytest.raises(ValueError, match="overwrite the input"):
        tiled.denoise_file(tmp_path / "in.npy", tmp_path / "in.npy", overwrite=True)
    assert (tmp_path / "out.npy").read_bytes() == b"keep"


@pytest.mark.parametrize("kwargs, error, match", [
    ({"tile_points": 0}, ValueError, "tile_points"),
    ({"client": 3}, TypeError, "client"),
    ({"preset": "paper"}, ValueError, "preset"),
    ({"iterations": 0}, ValueError, "iterations"),
    ({"select_scales": 1}, TypeError, "select_scales must be True, False or 'auto'"),
    ({"k": 30, "classification": np.zeros(50, int)}, ValueError, "do not take k=30 "),
    ({"classes": [2]}, ValueError, "classes and classification go together"),
    ({"classification": np.full(50, 2, np.uint8), "classes": "some"}, ValueError,
     "class codes, 'each' or 'all'"),
    ({"classification": np.full(50, 2, np.uint8), "classes": [6]}, ValueError,
     "no point is of class 6; the classes present are 2"),
    ({"classification": np.full(40, 2, np.uint8)}, ValueError, r"shape \(50,\)"),
])
def test_bad_file_arguments_are_named(tmp_path, kwargs, error, match):
    np.save(tmp_path / "in.npy", np.zeros((50, 3)))
    with pytest.raises(error, match=match):
        tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", **kwargs)
    assert [p.name for p in tmp_path.iterdir()] == ["in.npy"]
