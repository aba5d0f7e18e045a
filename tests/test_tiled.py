"""Tiled runs on Dask give the in-core result, bit for bit: the default method's rounds of tile
tasks on the one executor (pssd_fast.executor), tiles in memory or in files."""
import os
import warnings

import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets, executor, graph, method, tiled
from pssd_fast.tiled import binning, ondisk

from .conftest import refuse_new_files

pytest.importorskip("dask")

FIELDS = ("points", "normals", "likelihood", "feature_intensity", "displacement", "held")


@pytest.fixture(scope="module")
def noisy():
    """Noise about twice the spacing: cells of several points, some of them refined."""
    return datasets.cad_part(n_points=8_000, noise=0.02, seed=5)


@pytest.fixture(scope="module")
def in_core(noisy):
    return {preset: pssd_fast.denoise(noisy.points, preset=preset, extras=True)
            for preset in ("default", "fast")}


def _assert_same(got, expected):
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(got, field), getattr(expected, field),
                                      err_msg=field)
    np.testing.assert_array_equal(got.kept, expected.kept)
    for key in ("k", "noise", "plan", "n_iterations", "held_points"):
        assert got.stats[key] == expected.stats[key], key
    for ours, theirs in zip(got.stats["iterations"], expected.stats["iterations"]):
        # The tiles' residual sums are added tile by tile: their mean may differ in the last
        # bits.
        assert ours["mean_residual"] == pytest.approx(theirs["mean_residual"], rel=1e-12)
        assert {**ours, "times": None, "mean_residual": None} == {
            **theirs, "times": None, "mean_residual": None}


@pytest.mark.parametrize("preset", ["default", "fast"])
def test_threads_give_the_in_core_result(noisy, in_core, preset):
    got = tiled.denoise(noisy.points, preset=preset, tile_points=1_000, extras=True)
    assert got.stats["tiles"]["count"] >= 8
    assert got.stats["tiles"]["scheduler"] == "threads"
    if preset == "default":
        assert got.stats["iterations"][-1]["refined"] > 0
    _assert_same(got, in_core[preset])


def test_tiles_in_files_on_processes_give_the_in_core_result(noisy, in_core):
    """The local process pool: the tasks share the tiles' arrays through files. The
    likelihood and feature intensity, not asked for, are computed when first read, to the
    values the in-core run computed during the run."""
    got = tiled.denoise(noisy.points, tile_points=2_000, client="processes")
    assert got.stats["tiles"]["scheduler"] == "processes" and got.stats["tiles"]["count"] >= 4
    _assert_same(got, in_core["default"])


def test_tasks_at_once_share_the_cores(noisy, in_core, monkeypatch):
    """Dask's local schedulers run at most n_jobs threads in all, tasks at once times the
    threads of each, and say so in stats; the result stays the in-core one."""
    import contextlib
    import threading

    from pssd_fast._threads import resolve_n_jobs

    cores = resolve_n_jobs(2)
    lock, busy, most = threading.Lock(), [0], [0]
    real = executor.threads

    @contextlib.contextmanager
    def counted(n_jobs):
        with real(n_jobs) as n:
            with lock:
                busy[0] += n
                most[0] = max(most[0], busy[0])
            try:
                yield n
            finally:
                with lock:
                    busy[0] -= n

    monkeypatch.setattr(executor, "threads", counted)
    got = tiled.denoise(noisy.points, tile_points=1_000, n_jobs=2, extras=True)
    assert 0 < most[0] <= cores
    assert got.stats["tiles"]["threads"] == {"tasks_at_once": cores, "threads_per_task": 1}
    _assert_same(got, in_core["default"])
    alone = tiled.denoise(noisy.points, tile_points=1_000, n_jobs=2, client="sync",
                          extras=True)
    assert alone.stats["tiles"]["threads"] == {"tasks_at_once": 1, "threads_per_task": cores}
    _assert_same(alone, in_core["default"])


def test_the_threads_in_stats_are_those_of_one_round():
    """A round of one task takes every thread, a round of four tasks one each: stats give the
    second round's pair, not a pair of maxima that no round took."""
    from pssd_fast.tiled.scheduler import Runner

    runner = Runner("threads", 4, None)
    runner.map("one", 0, 1, lambda n_jobs: n_jobs, [()])
    assert runner.threads == {"tasks_at_once": 1, "threads_per_task": 4}
    assert runner.map("four", 0, 1, lambda i, n_jobs: n_jobs, [(i,) for i in range(4)]) == [1] * 4
    runner.map("one again", 0, 1, lambda n_jobs: n_jobs, [()])
    assert runner.threads == {"tasks_at_once": 4, "threads_per_task": 1}


@pytest.mark.slow  # a local cluster of processes: the killed-worker test below too
def test_a_local_cluster_of_two_processes_gives_the_in_core_result(noisy, in_core):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        got = tiled.denoise(noisy.points, tile_points=1_000, client=client, extras=True)
        assert got.stats["tiles"]["scheduler"] == "distributed"
        assert got.stats["tiles"]["count"] >= 8
        _assert_same(got, in_core["default"])
        # Each worker runs one task at a time: it gives that task all its cores.
        shares = client.run(tiled.scheduler._worker_threads)
        assert set(shares.values()) == {len(os.sched_getaffinity(0))}
        assert got.stats["tiles"]["threads"] == {
            "tasks_at_once": 2, "threads_per_task": len(os.sched_getaffinity(0))}
        # The scheduler's address does as well as the client.
        by_address = tiled.denoise(noisy.points, tile_points=4_000, extras=True,
                                   client=cluster.scheduler_address)
        _assert_same(by_address, in_core["default"])


def test_a_cloud_of_one_point_a_cell_tiles_alike():
    """Noise well under the spacing: cells of about one point, lists reaching across tiles."""
    points = datasets.cad_part(n_points=6_000, noise=0.002, seed=3).points
    expected = pssd_fast.denoise(points)
    got = tiled.denoise(points, tile_points=600, client="sync")
    assert got.stats["tiles"]["count"] >= 8
    assert expected.stats["iterations"][-1]["cells"] > 0.8 * len(points)
    _assert_same(got, expected)


@pytest.mark.usefixtures("small_chunks")
@pytest.mark.parametrize("offset, most", [([5e5, 5e6, 100.0], 3_999),
                                          ([300.0, 200.0, 100.0], 1_000)])
def test_a_stray_point_tiles_alike(tmp_path, monkeypatch, offset, most):
    """A "no return" row at the origin of a georeferenced cloud: the probe leaves it out of
    the spacing in memory and from a file alike, and the other points, all in one bin of the
    codes' first bits, are split by the next bits into tiles (and buckets) of at most
    ``tile_points``, as far as their cells have codes of their own (5e6 away they span more
    than 2**21 cells: runs of cells share a coarser code, which a tile holds whole; so the
    far case is only held below one tile of every point)."""
    points = np.vstack([datasets.cad_part(n_points=4_000, noise=0.003, seed=3).points + offset,
                        [0.0, 0.0, 0.0]])
    expected = pssd_fast.denoise(points)
    got = tiled.denoise(points, tile_points=1000, client="sync")
    _assert_same(got, expected)
    np.save(tmp_path / "in.npy", points)
    buckets = []
    made = binning.Buckets.__init__
    monkeypatch.setattr(binning.Buckets, "__init__",
                        lambda self, *args: (buckets.append(self), made(self, *args))[1])
    stats = tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", tile_points=1000,
                               client="sync")
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), expected.points)
    for tiles in (got.stats["tiles"], stats["tiles"]):
        assert tiles["count"] >= 3 and tiles["most_points"] <= most
    assert np.diff(buckets[0].starts).max() <= most


@pytest.mark.parametrize("keep", [False, True])
def test_given_normals_and_float32_tile_alike(keep):
    cloud = datasets.cad_part(n_points=6_000, noise=0.02, seed=6)
    points = cloud.points.astype(np.float32)
    expected = pssd_fast.denoise(points, -cloud.normals, keep_normals=keep)
    got = tiled.denoise(points, -cloud.normals, keep_normals=keep, tile_points=700,
                        client="sync")
    assert got.points.dtype == np.float32 and got.stats["tiles"]["count"] >= 8
    _assert_same(got, expected)


def test_shift_normals_tile_alike(noisy):
    expected = pssd_fast.denoise(noisy.points, shift_normals=False)
    got = tiled.denoise(noisy.points, shift_normals=False, tile_points=1_000)
    _assert_same(got, expected)


def test_tiles_orient_each_normal_alone(noisy, in_core):
    """Positions as in core; each normal turned on its own (in core, one tile propagates)."""
    expected = in_core["fast"]
    got = tiled.denoise(noisy.points, orient="up", preset="fast", tile_points=1_000)
    np.testing.assert_array_equal(got.points, expected.points)
    assert (got.normals[:, 2] >= 0).all()
    np.testing.assert_array_equal(np.abs(got.normals), np.abs(expected.normals))
    one = tiled.denoise(noisy.points, orient="up", preset="fast", tile_points=len(noisy.points))
    assert one.stats["tiles"]["count"] == 1
    np.testing.assert_array_equal(one.normals, pssd_fast.denoise(
        noisy.points, orient="up", preset="fast").normals)


def test_the_paper_s_pipeline_and_the_baselines_run_in_one_task():
    points = datasets.cad_part(n_points=3_000, noise=0.01, seed=2).points
    for options in ({"preset": "paper", "iterations": 1}, {"method": "mls"},
                    {"method": "bilateral", "remove_outliers": True}):
        got = tiled.denoise(points, tile_points=500, **options)
        assert got.stats["tiles"]["count"] == 1, options
        expected = pssd_fast.denoise(points, **options)
        for field in FIELDS:
            np.testing.assert_array_equal(getattr(got, field), getattr(expected, field))


def test_progress_hears_of_every_tile(noisy):
    """Each round's tiles as they finish (``tile_fit 3/8``), then the round's stages, in the
    iterations counted from 1 as the stages count them: in several tiles a round a step of
    each iteration on the means (the first shifts its normals)."""
    heard = []
    got = tiled.denoise(noisy.points, tile_points=1_000,
                        progress=lambda *args: heard.append(args))
    seen = [stage for _, _, stage, _ in heard]
    iterations = [(i, n) for i, n, _, _ in heard]
    assert iterations == sorted(iterations) and iterations[0] == (1, method.ITERATIONS)
    assert iterations[-1] == (method.ITERATIONS, method.ITERATIONS)
    count = got.stats["tiles"]["count"]
    rounds = {"tile_lists": method.ITERATIONS, "tile_shift": 1, "tile_filter": method.ITERATIONS,
              "tile_fit": method.ITERATIONS, "tile_project": 1, "tile_test": 1,
              "tile_refine": method.REFINE["iterations"]}
    for stage, times in rounds.items():
        ours = [s for s in seen if s.startswith(stage + " ")]
        assert len(ours) == times * count, stage
        assert ours[-1] == f"{stage} {count}/{count}"
    assert {"neighbors", "normals", "filter", "mls", "update", "project", "test",
            "refine_neighbors", "refine_fit"} <= set(seen)


@pytest.mark.parametrize("kwargs, error, match", [
    ({"tile_points": 0}, ValueError, "tile_points must be at least 500; got 0"),
    ({"tile_points": 499}, ValueError, "mostly the halo"),
    ({"tile_points": 1e6}, TypeError, "tile_points must be an integer"),
    ({"client": 3}, TypeError, "client"),
    ({"client": "bogus"}, ValueError, "neither a local scheduler .* nor a scheduler's address"),
    ({"sigma_n": -1.0}, ValueError, "sigma_n must be positive"),
    ({"iterations": 0}, ValueError, "iterations must be at least 1"),
    ({"preset": "fastest"}, ValueError, "unknown preset 'fastest'"),
    ({"method": "mls", "lam": 0.5}, ValueError, "lam"),
    ({"classes": [2]}, ValueError, "classes and classification go together"),
    ({"classification": np.zeros(100, np.uint8), "classes": "some"}, ValueError,
     "class codes, 'each' or 'all'"),
    ({"classification": np.zeros(100, np.uint8), "classes": [2]}, ValueError,
     "no point is of class 2; the classes present are 0"),
    ({"classification": np.full(100, 5, np.uint8)}, ValueError, "no point is of a surface"),
    ({"classification": np.zeros(10, np.uint8), "classes": [2]}, ValueError, r"shape \(100,\)"),
    ({"classification": np.zeros(100), "classes": [2]}, TypeError, "integers"),
    ({"sigma": 0.1}, TypeError, "unknown parameter"),
])
def test_bad_arguments_are_named(kwargs, error, match):
    with pytest.raises(error, match=match):
        tiled.denoise(np.random.default_rng(0).normal(size=(100, 3)), **kwargs)


def test_tiled_runs_show_denoise_s_parameters():
    """help() and editors see every parameter of pssd_fast.denoise, at its default, in both
    tiled runs' signatures, after their own."""
    import inspect

    from pssd_fast.parameters import PARAMETERS

    for func, own in ((tiled.denoise, ["points", "normals", "tile_points", "client"]),
                      (tiled.denoise_file, ["source", "destination", "tile_points", "client",
                                            "fields", "scratch", "overwrite"])):
        shown = inspect.signature(func).parameters
        assert list(shown) == own + [p.name for p in PARAMETERS]
        for name, parameter in inspect.signature(pssd_fast.denoise).parameters.items():
            if parameter.kind == inspect.Parameter.KEYWORD_ONLY:
                assert shown[name].default == parameter.default, name
                assert shown[name].kind == inspect.Parameter.KEYWORD_ONLY


def test_tiled_runs_take_denoise_s_parameters_at_their_defaults(tmp_path):
    """Every named parameter of pssd_fast.denoise, at its default, runs in both tiled runs (a
    file's points and normals are the file's)."""
    import inspect

    defaults = {name: p.default for name, p in inspect.signature(
        pssd_fast.denoise).parameters.items() if name not in ("points", "normals")}
    defaults.pop("method_params")
    defaults["iterations"] = 1
    points = datasets.cad_part(n_points=3_000, noise=0.01, seed=1).points
    expected = pssd_fast.denoise(points, iterations=1)
    got = tiled.denoise(points, tile_points=500, client="sync", **defaults)
    np.testing.assert_array_equal(got.points, expected.points)
    np.save(tmp_path / "in.npy", points)
    tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", tile_points=500,
                       client="sync", **defaults)
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), expected.points)


@pytest.fixture
def small_chunks(monkeypatch):
    """Chunks of a few thousand points: every pass crosses boundaries."""
    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 1_500)


@pytest.mark.usefixtures("small_chunks")
@pytest.mark.parametrize("preset, dtype, noise", [("default", np.float64, 0.02),
                                                  ("fast", np.float32, 0.02),
                                                  ("default", np.float32, 0.002)])
def test_a_file_tiled_out_of_core_gives_the_in_core_points(tmp_path, preset, dtype, noise):
    points = datasets.cad_part(n_points=8_000, noise=noise, seed=8).points.astype(dtype)
    source, out, scratch = tmp_path / "in.npy", tmp_path / "out.npy", tmp_path / "scratch"
    np.save(source, points)
    scratch.mkdir()
    expected = pssd_fast.denoise(points, preset=preset)
    stats = tiled.denoise_file(source, out, tile_points=1_000, preset=preset, client="sync",
                               scratch=scratch)
    got = np.load(out)
    assert got.dtype == dtype and stats["tiles"]["count"] >= 8
    assert stats["tiles"]["most_points"] <= 1_000
    np.testing.assert_array_equal(got, expected.points)
    if preset == "fast":  # one binning: in memory, the same tiles (once: the cheaper run)
        in_memory = tiled.denoise(points, tile_points=1_000, preset=preset, client="sync")
        assert {key: in_memory.stats["tiles"][key] for key in ("count", "most_points")} == {
            key: stats["tiles"][key] for key in ("count", "most_points")}
    for key in ("k", "noise", "plan", "held_points"):
        assert stats[key] == expected.stats[key], key
    assert [r.get("refined") for r in stats["iterations"]] == [
        r.get("refined") for r in expected.stats["iterations"]]
    assert list(scratch.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == [
        "in.npy", "out.npy", "scratch"]


@pytest.mark.usefixtures("small_chunks")
def test_codes_sorted_by_radix_give_the_same_points(tmp_path, monkeypatch):
    """Every sort of codes by radix (as on clouds of ``graph.RADIX_POINTS`` or more), in core
    and in a file's buckets: the points of numpy's stable sort."""
    points = datasets.cad_part(n_points=4_000, noise=0.005, seed=9).points
    source, out = tmp_path / "in.npy", tmp_path / "out.npy"
    np.save(source, points)
    expected = pssd_fast.denoise(points).points
    monkeypatch.setattr(graph, "RADIX_POINTS", 0)
    np.testing.assert_array_equal(pssd_fast.denoise(points).points, expected)
    tiled.denoise_file(source, out, tile_points=1_000, client="sync")
    np.testing.assert_array_equal(np.load(out), expected)


@pytest.mark.usefixtures("small_chunks")
@pytest.mark.parametrize("ext, normals", [(".las", False), (".laz", False), (".las", True),
                                          (".laz", True)])
def test_a_las_file_tiled_out_of_core_is_the_in_core_file(tmp_path, ext, normals):
    """Records, scale, offset, VLRs and EVLRs as read; the coordinates, normals, likelihood,
    feature intensity and displacement those of denoise, as the in-core writer stores them. A
    file with normals, by default: its normals updated and nothing added; without: every
    field asked for."""
    laspy = pytest.importorskip("laspy")
    from pssd_fast import io

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = [0.0001, 0.0001, 0.0001]
    header.offsets = [500_000.0, 4_000_000.0, 300.0]
    header.vlrs.append(laspy.VLR("pssd_test", 7, "a VLR", b"kept"))
    from laspy.vlrs.vlrlist import VLRList

    header.evlrs = VLRList([laspy.VLR("pssd_test", 8, "an EVLR", b"kept too")])
    cloud = datasets.cad_part(n_points=6_000, noise=0.02, seed=8)
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
    fields = () if normals else ondisk.RESULT_FIELDS
    result = pssd_fast.denoise(read.points, read.normals, extras=bool(fields))
    io.write(expected, read, points=result.points, normals=result.normals, fields={
        name: getattr(result, name).astype(np.float32)
        for name in ("likelihood", "feature_intensity", "displacement") if name in fields})
    # LAZ on threads, the default scheduler: its tasks read one file at once.
    stats = tiled.denoise_file(source, tmp_path / f"tiled{ext}", tile_points=800,
                               client="threads" if ext == ".laz" else "sync",
                               extras=bool(fields),
                               **({} if normals else {"fields": fields}))
    assert stats["tiles"]["count"] >= 6
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
    points = datasets.cad_part(n_points=6_000, noise=0.02, seed=4).points.astype(np.float32)
    group = zarr.open_group(str(tmp_path / "in.zarr"), mode="w")
    group.create_array("points", shape=points.shape, dtype=points.dtype, chunks=(1_024, 3))
    group["points"][:] = points
    (tmp_path / "out.zarr").mkdir()
    with pytest.raises(FileExistsError):
        tiled.denoise_file(tmp_path / "in.zarr", tmp_path / "out.zarr", tile_points=800)
    stats = tiled.denoise_file(tmp_path / "in.zarr", tmp_path / "out.zarr", tile_points=800,
                               overwrite=True)
    got = zarr.open_array(str(tmp_path / "out.zarr"), mode="r")
    assert stats["tiles"]["count"] >= 6 and got.chunks == (1_024, 3)
    np.testing.assert_array_equal(got[:], pssd_fast.denoise(points).points)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.zarr", "out.zarr"]


@pytest.mark.slow
@pytest.mark.parametrize("stage", ["bin", "tile_fit", "tile_refine", "write"])
def test_a_file_on_a_local_cluster_survives_a_killed_worker(tmp_path, stage, monkeypatch):
    """A worker killed while the file is binned, the tiles run or the output is written (in
    blocks of 5,000 rows): Dask runs its tasks again, the result stands."""
    import signal

    distributed = pytest.importorskip("distributed")
    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 5_000)
    points = datasets.cad_part(n_points=40_000, noise=0.02, seed=9).points
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


@pytest.mark.usefixtures("small_chunks")
def test_a_classified_las_file_is_split_by_the_tasks_that_read_it(tmp_path, monkeypatch):
    """Each class of a LAS file on its own, as in core; the tasks find their chunk's rows of a
    class from their own read (the calling process holds no row's class)."""
    laspy = pytest.importorskip("laspy")
    from pssd_fast import io

    cloud = datasets.cad_part(n_points=5_000, noise=0.02, seed=3)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = [0.0001, 0.0001, 0.0001]
    las = laspy.LasData(header)
    las.x, las.y, las.z = (cloud.points * 100).T
    las.classification = np.where(np.arange(5_000) % 3 == 0, 6, 2).astype(np.uint8)
    las.classification[:40] = 1
    las.write(str(tmp_path / "scan.las"))
    read = io.read(tmp_path / "scan.las")
    whole = pssd_fast.denoise(read.points, classification=read.fields["classification"],
                              classes="each", iterations=1)
    io.write(tmp_path / "in_core.las", read, points=whole.points)
    masks = []
    chunk = ondisk.chunk
    monkeypatch.setattr(ondisk, "chunk", lambda array, start, stop, mask=None: (
        masks.append(mask), chunk(array, start, stop, mask))[1])
    stats = tiled.denoise_file(tmp_path / "scan.las", tmp_path / "tiled.las", tile_points=900,
                               client="sync", classes="each", iterations=1)
    assert sorted(stats["classes"]["runs"]) == [1, 2, 6]
    assert {type(mask) for mask in masks} == {ondisk.Classes}
    got, want = (laspy.read(str(tmp_path / name)) for name in ("tiled.las", "in_core.las"))
    np.testing.assert_array_equal(got.points.array, want.points.array)


@pytest.mark.slow  # Dask's local process pool
def test_tasks_read_bin_and_write_a_file_the_caller_never_reads(tmp_path, monkeypatch):
    """Every pass over the points runs in the tasks' processes: the calling process fails
    wherever it would read the input's rows or a task's records, and the result is still the
    in-core one, bit for bit; with chunks and blocks of a few thousand rows, rows at the
    position of earlier rows (copied across blocks) and classes kept in place by tasks."""
    cloud = datasets.cad_part(n_points=5_000, noise=0.02, seed=8).points
    points = np.vstack([cloud, cloud[::97], cloud[4_000:4_010]])
    labels = np.where(np.arange(points.shape[0]) % 50 == 0, 7, 2).astype(np.uint8)
    np.save(tmp_path / "in.npy", points)
    expected = pssd_fast.denoise(points, classification=labels, classes=[2], iterations=1)
    monkeypatch.setattr(ondisk, "CHUNK_POINTS", 1_500)  # here: the tasks get their rows

    def refused(*args, **kwargs):
        raise AssertionError("the calling process read rows")

    monkeypatch.setattr(ondisk.NpyFile, "__getitem__", refused)
    monkeypatch.setattr(ondisk, "read_pieces", refused)
    seen = set()
    stats = tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", tile_points=1_000,
                               client="processes", n_jobs=2, classification=labels,
                               classes=[2], iterations=1,
                               progress=lambda i, n, stage, s: seen.add(
                                   (i, n, stage.split(" ")[0])))
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), expected.points)
    assert stats["duplicates"] == expected.stats["duplicates"] > 0
    # The passes before the plan are iteration 0 of 0; those after it, of the last iteration.
    assert {(0, 0, "read"), (0, 0, "bin"), (0, 0, "merge"), (0, 0, "cells"), (1, 1, "parts"),
            (1, 1, "copied"), (1, 1, "kept"), (1, 1, "write")} <= seen
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.npy", "out.npy"]


def test_a_failing_tile_leaves_no_output_and_no_scratch(tmp_path, monkeypatch):
    np.save(tmp_path / "in.npy", datasets.cad_part(n_points=4_000, noise=0.02, seed=8).points)

    def fail(*args):
        raise RuntimeError("a tile failed")

    monkeypatch.setattr(method, "project", fail)
    with pytest.raises(RuntimeError, match="a tile failed"):
        tiled.denoise_file(tmp_path / "in.npy", tmp_path / "out.npy", tile_points=500,
                           client="sync")
    assert [p.name for p in tmp_path.iterdir()] == ["in.npy"]


def test_a_read_only_output_folder_is_refused_before_the_work(tmp_path, monkeypatch):
    """Scratch elsewhere, the output's folder is tried before the input is read (root ignores
    permission bits: the refusal is simulated where the trial file is created)."""
    np.save(tmp_path / "in.npy", np.zeros((50, 3)))
    (tmp_path / "rodir").mkdir()
    (tmp_path / "scratch").mkdir()

    refuse_new_files(monkeypatch)
    monkeypatch.setattr(ondisk, "NpyFile", None)  # reading the input would fail otherwise
    with pytest.raises(PermissionError, match=f"output folder {tmp_path / 'rodir'} is not "
                                              "writable"):
        tiled.denoise_file(tmp_path / "in.npy", tmp_path / "rodir" / "out.npy",
                           scratch=tmp_path / "scratch")


def test_a_float32_file_far_from_the_origin_warns_as_a_float32_array_does(tmp_path):
    points = datasets.cad_part(n_points=3000, noise=0.003, seed=1).points * 100
    for name, offset, warns in (("far", [4.5e5, 4e6, 100.0], True), ("near", 0.0, False)):
        np.save(tmp_path / f"{name}.npy", (points + offset).astype(np.float32))
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            tiled.denoise_file(tmp_path / f"{name}.npy", tmp_path / f"{name}_out.npy",
                               tile_points=1000, client="sync", iterations=1)
        said = [str(w.message) for w in seen if issubclass(w.category, pssd_fast.DenoiseWarning)]
        assert bool(said) == warns, said
        assert not said or said[0].startswith("points are float32 and reach 4000")


@pytest.mark.parametrize("name, write, error, match", [
    ("in.xyz", None, ValueError, "reads .npy into .npy"),
    ("in.npy", np.array([[0.0, 0.0, np.nan]] * 50), ValueError, "row 0"),
    ("in.npy", np.zeros((50, 3), np.complex128), TypeError, "real numbers"),
    ("in.npy", np.zeros((50, 2)), ValueError, r"shape \(n, 3\)"),
    ("in.npy", np.random.default_rng(0).normal(size=(50, 3)) * 1e160, ValueError,
     "rescale the cloud"),
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


#: What denoise_file refuses on purpose: it never holds every point, which these need.
NEEDS_EVERY_POINT = "denoise_file runs the default method .* needs? them all"


@pytest.mark.parametrize("kwargs, error, match", [
    ({"tile_points": 5}, ValueError, "tile_points must be at least 500; got 5"),
    ({"client": 3}, TypeError, "client"),
    ({"client": "bogus"}, ValueError, "neither a local scheduler .* nor a scheduler's address"),
    ({"iterations": 0}, ValueError, "iterations"),
    ({"sigma": 1.0}, TypeError, "unknown parameter"),
    ({"fields": ["colour"]}, ValueError, "unknown field"),
    ({"preset": "paper"}, ValueError, "point; preset='paper' needs them all"),
    ({"method": "mls"}, ValueError, "point; method='mls' needs them all"),
    ({"method": "bilateral"}, ValueError, NEEDS_EVERY_POINT),
    ({"remove_outliers": True}, ValueError, "remove_outliers needs them all"),
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


@pytest.mark.parametrize("tile_points", [None, 2_000])
def test_a_run_holds_only_what_its_later_rounds_read(noisy, in_core, tile_points):
    """Each round's entries go once no later round reads them: after the run the store holds
    the tiles' points and first means, the last fits (the fields computed when read) and the
    output, and the output is the in-core run's."""
    from pssd_fast.denoise import run
    from pssd_fast.store import Memory

    store = Memory()
    got = run(noisy.points, None, {}, tile_points=tile_points, store=store)
    assert got.stats["iterations"][-1]["refined"] > 0
    kinds = sorted({key[0] for key in store.entries})
    assert kinds == ["cells", "fits", "out", "points"]
    assert {key[2] for key in store.entries if key[0] == "cells"} == {0}
    _assert_same(got, in_core["default"])


@pytest.mark.parametrize("kind", ["memory", "files"])
def test_a_store_gives_back_what_was_put_and_the_rows_asked(kind, tmp_path):
    """Whole entries, the names asked, the rows asked (from files: through a memory map), an
    entry put again with fewer names, values that are not arrays, and entries dropped."""
    from pssd_fast.store import Files, Memory

    store = Memory() if kind == "memory" else Files(tmp_path)
    rng = np.random.default_rng(0)
    xyz, gid = rng.normal(size=(50, 3)), np.arange(50, 100)
    store.put(("cells", 0, 1), {"xyz": xyz, "gid": gid, "picks": [(1, np.arange(3)), (2, None)]})
    got = store.get(("cells", 0, 1))
    assert sorted(got) == ["gid", "picks", "xyz"]
    np.testing.assert_array_equal(got["xyz"], xyz)
    assert got["picks"][1] == (2, None)
    np.testing.assert_array_equal(got["picks"][0][1], np.arange(3))
    rows = np.array([0, 7, 49])
    part = store.rows(("cells", 0, 1), ("gid", "xyz"), rows)
    np.testing.assert_array_equal(part["gid"], gid[rows])
    np.testing.assert_array_equal(part["xyz"], xyz[rows])
    assert store.rows(("cells", 0, 1), ("gid",), rows[:0])["gid"].shape == (0,)
    store.put(("cells", 0, 1), {"xyz": xyz[:5]})
    assert list(store.get(("cells", 0, 1))) == ["xyz"]
    store.drop(("cells", 0, 1))
    store.drop(("cells", 0, 1))  # twice: nothing left to drop
    with pytest.raises((KeyError, FileNotFoundError)):
        store.get(("cells", 0, 1), ("xyz",))
    if kind == "files":
        assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("targets, sorted_", [(1, True), (3, True), (7, False),
                                                (70_000, False)])
def test_records_are_saved_in_the_stable_order_of_their_targets(tmp_path, targets, sorted_):
    """Whether the records come in order, few targets (a radix sort) or many, the file holds
    them as a stable sort by target puts them, and the counts are the targets'."""
    rng = np.random.default_rng(targets)
    target = rng.integers(0, targets, 5000)
    if sorted_:
        target.sort()
    records = np.zeros(5000, ondisk.part_dtype(("xyz",)))
    records["row"] = np.arange(5000)
    records["xyz"] = rng.normal(size=(5000, 3))
    counts = ondisk.sorted_save(records, target, targets, tmp_path / "part.bin")
    saved = np.fromfile(tmp_path / "part.bin", records.dtype)
    assert saved.tobytes() == records[np.argsort(target, kind="mergesort")].tobytes()
    np.testing.assert_array_equal(counts, np.bincount(target, minlength=targets))


@pytest.mark.parametrize("ranks", [[], [0], [3, 4, 5, 900, 901, 90_000, 199_999],
                                   list(range(0, 200_000, 7)), [5, 100_000, 150_000]])
def test_the_probe_s_sample_is_read_from_a_bucket_by_rank(tmp_path, ranks):
    """Ranks near each other are read in runs, far ones alone: either way each record's own
    field, in the ranks' order."""
    from pssd_fast.tiled import binning

    records = np.zeros(200_000, binning.RECORD)
    records["xyz"] = np.random.default_rng(4).normal(size=(200_000, 3))
    records.tofile(tmp_path / "bucket.bin")
    ranks = np.array(ranks, np.int64)
    got = binning._sample(tmp_path / "bucket.bin", binning.RECORD, "xyz", ranks, 1)
    assert got.tobytes() == records["xyz"][ranks].tobytes()


def test_records_are_taken_whole_and_pieces_read_into_place(tmp_path):
    """ondisk.take gives numpy's indexing of the records; read_pieces joins pieces of files in
    order and names a file that ends before a piece does."""
    from pssd_fast.tiled import binning

    rng = np.random.default_rng(5)
    records = np.zeros(3000, binning.RECORD_NORMALS)
    records["row"] = rng.permutation(3000)
    records["code"] = rng.integers(0, 2**63, 3000, dtype=np.uint64)
    records["xyz"], records["nrm"] = rng.normal(size=(3000, 3)), rng.normal(size=(3000, 3))
    for order in (rng.permutation(3000), np.arange(0, 3000, 7), np.arange(0)):
        assert ondisk.take(records, order).tobytes() == records[order].tobytes()
    records[:1000].tofile(tmp_path / "a.bin")
    records[1000:].tofile(tmp_path / "b.bin")
    found = [(tmp_path / "a.bin", 10, 990), (tmp_path / "b.bin", 0, 5),
             (tmp_path / "b.bin", 1500, 500)]
    want = np.concatenate([records[10:1000], records[1000:1005], records[2500:3000]])
    assert ondisk.read_pieces(found, records.dtype).tobytes() == want.tobytes()
    assert ondisk.read_pieces([], records.dtype).shape == (0,)
    with pytest.raises(OSError, match="b.bin: the file ends"):
        ondisk.read_pieces([(tmp_path / "b.bin", 1990, 20)], records.dtype)
