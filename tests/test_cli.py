"""The ``pssd`` command end to end, in a subprocess, errors included."""
import subprocess
import sys

import numpy as np
import pytest

import pssd_fast
from pssd_fast import cli, datasets

plyfile = pytest.importorskip("plyfile")
laspy = pytest.importorskip("laspy")


def pssd(*args, cwd=None):
    """Run ``pssd ARGS`` as a user would; return (status, stdout, stderr)."""
    done = subprocess.run([sys.executable, "-m", "pssd_fast.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=600)
    return done.returncode, done.stdout, done.stderr


def assert_one_line_error(status, err, match):
    assert status == 1
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pssd: error: ") and match in lines[0], err


@pytest.fixture(scope="module")
def cloud():
    return datasets.cad_part(n_points=3000, noise=0.003, seed=1)


@pytest.fixture
def ply_with_extras(tmp_path, cloud):
    """A binary PLY with colours, a quality scalar and a face element."""
    n = len(cloud.points)
    vertex = np.empty(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"),
                                ("green", "u1"), ("blue", "u1"), ("quality", "f4")])
    for axis, name in enumerate("xyz"):
        vertex[name] = cloud.points[:, axis]
    rng = np.random.default_rng(0)
    for name in ("red", "green", "blue"):
        vertex[name] = rng.integers(0, 256, n)
    vertex["quality"] = rng.uniform(size=n)
    faces = np.empty(2, dtype=[("vertex_indices", "i4", (3,))])
    faces["vertex_indices"] = [[0, 1, 2], [2, 3, 4]]
    path = tmp_path / "scan.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex"),
                     plyfile.PlyElement.describe(faces, "face")]).write(str(path))
    return path, vertex


def test_help_is_complete():
    status, out, _ = pssd("denoise", "--help")
    assert status == 0
    for option in ["--method", "--iterations", "--preset", "--k", "--lam", "--n-jobs",
                   "--keep-normals", "--rebuild-graph", "--no-rebuild-graph",
                   "--force", "--quiet", "--verbose"] + [
                       "--" + d.replace("_", "-") for d in cli.METHOD_OPTIONS]:
        assert option in out
    for command in ("demo", "info", "render"):
        status, out, _ = pssd(command, "--help")
        assert status == 0 and "usage: pssd " + command in out


def test_denoise_ply_keeps_every_other_attribute(tmp_path, ply_with_extras):
    path, vertex = ply_with_extras
    out = tmp_path / "clean.ply"
    status, stdout, err = pssd("denoise", path, out, "--iterations", "1", "--verbose")
    assert status == 0, err
    assert "iteration 1: neighbors" in stdout
    data = plyfile.PlyData.read(str(out))
    written = data["vertex"].data
    for name in ("red", "green", "blue", "quality"):
        np.testing.assert_array_equal(written[name], vertex[name])
    np.testing.assert_array_equal(data["face"].data["vertex_indices"][1], [2, 3, 4])
    for name in ("likelihood", "feature_intensity", "displacement", "nx", "ny", "nz"):
        assert name in written.dtype.names
    moved = np.column_stack([written[a] for a in "xyz"])
    original = np.column_stack([vertex[a] for a in "xyz"])
    assert np.abs(moved - original).max() > 0
    np.testing.assert_allclose(np.linalg.norm(moved - original, axis=1),
                               written["displacement"], atol=1e-6)
    # The input is untouched, and an existing output is not replaced without --force.
    again = plyfile.PlyData.read(str(path))["vertex"].data
    np.testing.assert_array_equal(again, vertex)
    assert_one_line_error(*pssd("denoise", path, out)[::2], "--force")
    assert pssd("denoise", path, out, "--force", "--quiet", "--iterations", "1")[0] == 0


def test_denoise_las_keeps_records_and_georeference(tmp_path, cloud):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001, 0.001, 0.001]
    header.offsets = [500_000.0, 4_000_000.0, 300.0]
    las = laspy.LasData(header)
    utm = cloud.points * 100 + [500_123.0, 4_000_456.0, 310.0]  # a 100 m part, UTM-like
    las.x, las.y, las.z = utm.T
    rng = np.random.default_rng(2)
    las.intensity = rng.integers(0, 65535, len(utm))
    las.classification = rng.integers(0, 10, len(utm))
    las.gps_time = rng.uniform(0, 1e5, len(utm))
    path = tmp_path / "scan.las"
    las.write(str(path))
    out = tmp_path / "clean.las"
    status, _, err = pssd("denoise", path, out, "--iterations", "1", "--quiet")
    assert status == 0, err
    before, after = laspy.read(str(path)), laspy.read(str(out))
    np.testing.assert_array_equal(after.header.scales, before.header.scales)
    np.testing.assert_array_equal(after.header.offsets, before.header.offsets)
    for name in ("intensity", "classification", "gps_time", "return_number"):
        np.testing.assert_array_equal(np.asarray(after[name]), np.asarray(before[name]))
    # The coordinates are those of an in-memory denoise, quantised to the file's millimetres.
    read_back = np.column_stack([before.x, before.y, before.z])
    expected = pssd_fast.denoise(read_back, iterations=1).points
    moved = np.column_stack([after.x, after.y, after.z])
    assert np.abs(moved - expected).max() <= 0.5e-3 + 1e-9
    assert np.abs(moved - read_back).mean() > 1e-2
    assert "likelihood" in after.point_format.extra_dimension_names


def test_info_and_render(tmp_path, ply_with_extras):
    path, _ = ply_with_extras
    status, out, err = pssd("info", path)
    assert status == 0, err
    assert "3,000 points" in out and "red (uint8)" in out and "average spacing" in out
    png = tmp_path / "feature.png"
    status, out, err = pssd("render", path, "-o", png, "--color", "feature")
    assert status == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert_one_line_error(*pssd("render", path, "-o", tmp_path / "d.png", "--color",
                                "displacement")[::2], "holds no displacement")


def test_demo_writes_files_and_pictures(tmp_path):
    folder = tmp_path / "demo"
    status, out, err = pssd("demo", "--out", folder, "--points", "3000", "--iterations", "1")
    assert status == 0, err
    assert "| Robust (default) | 1 |" in out
    names = {p.name for p in folder.iterdir()}
    assert {"noisy.ply", "denoised.ply", "noisy.png", "curvature.png", "likelihood.png",
            "feature.png", "denoised_curvature.png", "denoised_displacement.png"} <= names
    assert_one_line_error(*pssd("demo", "--out", folder, "--points", "3000")[::2], "--force")


@pytest.mark.parametrize("args, match", [
    (["denoise", "missing.ply", "out.ply"], "missing.ply"),
    (["denoise", "in.xyz", "out.ply", "--method", "mls", "--radius-factor", "3"],
     "--radius-factor is not a parameter of method 'mls'"),
    (["denoise", "in.xyz", "out.unknown"], "unknown"),
    (["denoise", "in.xyz", "out.ply", "--k", "5"], "k must be at least 10"),
    (["denoise", "in.xyz", "nowhere/out.ply"], "does not exist"),
    (["info", "truncated.ply"], "truncated.ply"),
    (["info", "malformed.xyz"], "malformed.xyz"),
    (["info", "truncated.las"], "truncated.las"),
    (["denoise", "in.xyz", "in.xyz/out.ply"], "is not a folder"),
    (["info", "."], "."),
])
def test_errors_are_one_line(tmp_path, cloud, args, match):
    np.savetxt(tmp_path / "in.xyz", cloud.points)
    (tmp_path / "malformed.xyz").write_text("0 0 0\n1 1 one\n")
    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.x, las.y, las.z = cloud.points.T
    las.write(str(tmp_path / "whole.las"))
    whole = (tmp_path / "whole.las").read_bytes()
    (tmp_path / "truncated.las").write_bytes(whole[: len(whole) // 2])
    (tmp_path / "truncated.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\n"
        b"property float x\nproperty float y\nproperty float z\nend_header\n" + b"\0" * 100)
    status, _, err = pssd(*args, cwd=tmp_path)
    assert_one_line_error(status, err, match)
    assert not (tmp_path / "out.ply").exists()


def test_a_failing_write_leaves_nothing(tmp_path, cloud, monkeypatch, capsys):
    """A full disk during the write: one error line, status 1, no output, no temporary file."""
    import errno
    import os

    source = tmp_path / "in.xyz"
    np.savetxt(source, cloud.points)
    before = source.read_bytes()
    real_replace = os.replace

    def full_disk(src, dst):
        if str(dst).endswith("out.ply"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", full_disk)
    status = cli.main(["denoise", str(source), str(tmp_path / "out.ply"), "--iterations", "1",
                       "--quiet"])
    err = capsys.readouterr().err
    assert_one_line_error(status, err, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.xyz"]
    assert source.read_bytes() == before


@pytest.mark.parametrize("flag, rebuild", [("--rebuild-graph", True),
                                           ("--no-rebuild-graph", False)])
def test_graph_reuse_reaches_the_library(tmp_path, cloud, flag, rebuild):
    source, out = tmp_path / "in.npy", tmp_path / "out.npz"
    np.save(source, cloud.points)
    status = cli.main(["denoise", str(source), str(out), "--preset", "paper", "--iterations",
                       "2", flag, "--quiet"])
    assert status == 0
    expected = pssd_fast.denoise(cloud.points, preset="paper", iterations=2,
                                 rebuild_graph=rebuild)
    np.testing.assert_array_equal(np.load(out)["points"], expected.points)


def test_an_unwritable_folder_is_one_line(tmp_path, cloud, monkeypatch, capsys):
    """Root ignores permission bits, so the refusal is simulated where the file is created."""
    import builtins

    from pssd_fast.io import _common

    source = tmp_path / "in.xyz"
    np.savetxt(source, cloud.points)

    def refuse(file, mode="r", *args, **kwargs):
        if "x" in mode:
            raise PermissionError(13, "Permission denied", str(file))
        return builtins.open(file, mode, *args, **kwargs)

    monkeypatch.setattr(_common, "open", refuse, raising=False)  # atomic_write's open
    status = cli.main(["denoise", str(source), str(tmp_path / "out.ply"), "--iterations", "1",
                       "--quiet"])
    assert_one_line_error(status, capsys.readouterr().err, "Permission denied")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.xyz"]


@pytest.mark.parametrize("preset, iterations", [("default", 4), ("paper", 2)])
def test_quick_start_demo_reports_the_preset(capsys, preset, iterations):
    from pssd_fast.__main__ import main

    assert main(["--points", "3000", "--preset", preset]) == 0
    out = capsys.readouterr().out
    assert f"preset '{preset}': {iterations} iterations" in out
    assert "within 1% of a sharp edge, mean" in out


def _terrain_las(path, n=4000, outliers=0):
    """A hilly LAS terrain with intensities, and ``outliers`` points scattered above it."""
    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 100, (n, 2))
    z = 5 * np.sin(xy[:, 0] / 15) * np.cos(xy[:, 1] / 20) + rng.normal(0, 0.05, n)
    points = np.column_stack([xy, z])
    points = np.vstack([points, rng.uniform([0, 0, -10], [100, 100, 30], (outliers, 3))])
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001, 0.001, 0.001]
    header.offsets = [500_000.0, 4_000_000.0, 300.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = (points + [500_000.0, 4_000_000.0, 300.0]).T
    las.intensity = np.arange(len(points)) % 65535
    las.write(str(path))
    return points


def test_las_normals_point_up_and_outliers_are_dropped(tmp_path):
    """LAS input: normals up by default; --remove-outliers drops the flagged records (the
    others keep their own intensity) and every output point carries a float32 outlier_score."""
    _terrain_las(tmp_path / "scan.las", outliers=40)
    out = tmp_path / "clean.las"
    status, text, err = pssd("denoise", tmp_path / "scan.las", out, "--preset", "fast",
                             "--remove-outliers")
    assert status == 0, err
    after = laspy.read(str(out))
    assert (np.asarray(after["nz"]) > 0).all()
    kept = np.asarray(after.intensity).astype(np.int64)
    assert 4000 - 20 <= len(kept) < 4040 and (kept >= 4000).sum() <= 4
    assert np.asarray(after["outlier_score"]).dtype == np.float32
    assert (np.asarray(after["outlier_score"]) <= 1).all()
    assert "outliers removed" in text
    status, _, err = pssd("denoise", tmp_path / "scan.las", tmp_path / "all.las",
                          "--preset", "fast", "--orient", "0,0,-1000")
    assert status == 0, err
    every = laspy.read(str(tmp_path / "all.las"))
    # The terrain faces the viewpoint below it; the 40 scattered points have no surface.
    assert len(every.x) == 4040 and (np.asarray(every["nz"])[:4000] < 0).all()


def test_orient_and_removal_errors(tmp_path, ply_with_extras):
    path, _ = ply_with_extras
    status, _, err = pssd("denoise", path, tmp_path / "out.ply", "--remove-outliers",
                          "--iterations", "1")
    assert_one_line_error(status, err, "cannot drop vertices of a PLY file that also holds face")
    assert not (tmp_path / "out.ply").exists()
    status, _, err = pssd("denoise", path, tmp_path / "out.ply", "--orient", "left")
    assert status == 2 and "expected outward, up or a viewpoint X,Y,Z" in err
