"""The ``pssd`` command end to end, errors included: through ``cli.main``, which the console
script calls, and in a subprocess where the process itself is the subject (stdin and stdout,
signals)."""
import gzip
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pssd_fast
from pssd_fast import cli, datasets, method
from pssd_fast.denoise import METHOD_DEFAULTS

from .conftest import data_file, pssd, refuse_new_files

plyfile = pytest.importorskip("plyfile")
laspy = pytest.importorskip("laspy")


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


def test_help_offers_every_parameter_of_the_library():
    status, out, _ = pssd("denoise", "--help")
    assert status == 0
    # Every parameter of denoise and of its methods, but those a file gives (normals, classes
    # of its points) or the terminal replaces (progress: the bar, --quiet).
    # extras: what --fields asks for.
    names = set(inspect.signature(pssd_fast.denoise).parameters) - {
        "points", "normals", "classification", "progress", "extras", "method_params"}
    names |= {name for params in METHOD_DEFAULTS.values() for name in params}
    options = {name: name.replace("_", "-").replace("n-jobs", "threads") for name in names}
    missing = [name for name, option in sorted(options.items())
               if f"--{option}" not in out and f"--no-{option}" not in out]
    assert not missing, missing
    for command in ("demo", "info", "render"):
        status, out, _ = pssd(command, "--help")
        assert status == 0 and "usage: pssd " + command in out


def test_denoise_ply_keeps_every_other_attribute(tmp_path, ply_with_extras):
    path, vertex = ply_with_extras
    out = tmp_path / "clean.ply"
    status, stdout, err = pssd("denoise", path, out, "--iterations", "1", "--verbose",
                               "--fields", "all")
    assert status == 0, err
    assert "iteration 1: neighbors" in stdout
    xyz = np.column_stack([vertex[a] for a in "xyz"]).astype(np.float64)
    stats = pssd_fast.denoise(xyz, iterations=1).stats
    noise = stats["plan"]["noise"]
    assert (f"k = {stats['k']} cell means within {stats['plan']['bound']:.4g}, from the probe's "
            f"noise {noise['sigma']:.4g} and spacing {noise['spacing']:.4g}" in stdout)
    data = plyfile.PlyData.read(str(out))
    written = data["vertex"].data
    for name in ("red", "green", "blue", "quality"):
        np.testing.assert_array_equal(written[name], vertex[name])
    np.testing.assert_array_equal(data["face"].data["vertex_indices"][1], [2, 3, 4])
    for name in ("likelihood", "feature_intensity", "displacement", "outlier_score", "held",
                 "nx", "ny", "nz"):
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


def test_an_output_that_appears_during_the_run_is_kept(tmp_path, small, monkeypatch, capsys):
    """Another program writes the output while the cloud is denoised: its file is kept, and
    the refusal names --force, as the check before the run does, not the Python keyword."""
    from pssd_fast import io

    np.savetxt(tmp_path / "in.xyz", small)
    out = tmp_path / "out.xyz"
    write = io.write

    def late(path, *args, **kwargs):
        out.write_text("OTHER")
        return write(path, *args, **kwargs)

    monkeypatch.setattr(io, "write", late)
    status = cli.main(["denoise", str(tmp_path / "in.xyz"), str(out), "--iterations", "1"])
    err = capsys.readouterr().err
    assert_one_line_error(status, err, f"{out} exists; pass --force to overwrite it")
    assert "overwrite=True" not in err and out.read_text() == "OTHER"


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
    status, out, err = pssd("info", path)
    assert status == 0, err
    low = np.column_stack([las.x, las.y, las.z]).min(axis=0)
    assert f"bounds: min ({low[0]:.3f}, {low[1]:.3f}, {low[2]:.3f})," in out  # mm, not 4e+06
    assert ("LAS 1.2, point format 3, scale (0.001, 0.001, 0.001), offset (500000, 4000000, "
            "300)") in out
    out = tmp_path / "clean.las"
    # Its classes 0 to 9 are random: denoised as one cloud.
    status, _, err = pssd("denoise", path, out, "--iterations", "1", "--quiet", "--classes",
                          "all")
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
    assert list(after.point_format.dimension_names) == list(before.point_format.dimension_names)


def test_output_has_the_input_attributes_only(tmp_path, ply_with_extras):
    """By default PLY, text and LAS outputs hold the input's attributes and nothing more (an
    input's own normals updated); ``--fields normals`` adds normals."""
    path, vertex = ply_with_extras
    fast = ("--preset", "fast", "--quiet")
    assert pssd("denoise", path, tmp_path / "out.ply", *fast)[0] == 0
    written = plyfile.PlyData.read(str(tmp_path / "out.ply"))
    assert written["vertex"].data.dtype == vertex.dtype
    assert written["face"].count == 2
    cloud = pssd_fast.io.read(path)
    np.savetxt(tmp_path / "in.xyz", cloud.points, header="x y z", comments="# ")
    assert pssd("denoise", tmp_path / "in.xyz", tmp_path / "out.xyz", *fast)[0] == 0
    lines = (tmp_path / "out.xyz").read_text().splitlines()
    assert lines[0] == "# x y z" and len(lines[1].split()) == 3
    assert pssd("denoise", tmp_path / "in.xyz", tmp_path / "n.xyz", *fast, "--fields",
                "normals")[0] == 0
    assert (tmp_path / "n.xyz").read_text().splitlines()[0] == "# x y z nx ny nz"
    normals = np.tile([0.0, 0.0, 1.0], (len(cloud.points), 1))
    pssd_fast.io.write(tmp_path / "with.las", pssd_fast.io.PointCloud(cloud.points, normals))
    assert pssd("denoise", tmp_path / "with.las", tmp_path / "with_out.las", *fast)[0] == 0
    before, after = (laspy.read(str(tmp_path / name)) for name in ("with.las", "with_out.las"))
    assert list(after.point_format.dimension_names) == list(before.point_format.dimension_names)
    assert np.abs(np.asarray(after["nz"]) - 1).max() > 1e-3  # the normals were updated


def test_info_and_render(tmp_path, ply_with_extras):
    path, _ = ply_with_extras
    status, out, err = pssd("info", path)
    assert status == 0, err
    assert "3,000 points" in out and "red (uint8)" in out and "average spacing" in out
    # One stray row set the average alone (1.49 to 11.1 on Autzen): it is left out, and said.
    cloud = pssd_fast.io.read(path)
    spacing = float(re.search(r"other point\): ([0-9.e+-]+)", out).group(1))
    far = np.vstack([cloud.points, [1e9, 1e9, 1e9]])
    pssd_fast.io.write(tmp_path / "far.xyz", pssd_fast.io.PointCloud(far))
    status, far_out, err = pssd("info", tmp_path / "far.xyz")
    assert status == 0, err
    assert re.search(rf"other point\): {spacing:.6g}; 1 point farther than 100 times the median "
                     r"from every other left out \(stray\?\)", far_out), far_out
    assert "other elements: face (2)" in out
    jpg = tmp_path / "feature.jpg"
    status, out, err = pssd("render", path, "-o", jpg, "--color", "feature", "--preset", "fast")
    assert status == 0, err
    assert jpg.read_bytes()[:3] == b"\xff\xd8\xff"
    assert "(up axis z, view 50 " in out  # the part is flat: seen as a scene
    assert_one_line_error(*pssd("render", path, "-o", tmp_path / "f.gif")[::2],
                          "cannot write a picture with extension '.gif'")
    assert_one_line_error(*pssd("render", path, "-o", tmp_path / "d.png", "--color",
                                "displacement")[::2], "holds no displacement")


def test_render_computes_the_fields_pssd_denoise_stores(tmp_path, ply_with_extras):
    from pssd_fast import io
    from pssd_fast.pictures.fields import field_values

    path, _ = ply_with_extras
    status, _, err = pssd("denoise", path, tmp_path / "out.ply", "--iterations", "2", "--quiet",
                          "--fields", "feature_intensity,likelihood")
    assert status == 0, err
    raw, out = io.read(path), io.read(tmp_path / "out.ply")
    assert "feature_intensity" not in raw.fields and "feature_intensity" in out.fields
    for name in ("feature", "likelihood"):
        stages = []
        computed = field_values(name, raw.points, raw.normals, raw.fields, iterations=2,
                                progress=lambda i, n, stage, s: stages.append((i, n, stage)))
        np.testing.assert_array_equal(computed, field_values(name, out.points, out.normals,
                                                             out.fields))
        assert (2, 2, "extras") in stages and (1, 2, "normals") in stages  # progress
    # Curvature is one measure of the drawn points, whatever else the file holds.
    np.testing.assert_array_equal(field_values("curvature", raw.points, stored=out.fields),
                                  field_values("curvature", raw.points))


def test_render_shades_a_file_without_normals(tmp_path):
    sphere = datasets.sphere(3000, noise=0.0, seed=3).points
    path = tmp_path / "sphere.npz"
    np.savez(path, points=sphere, displacement=np.zeros(len(sphere)))
    status, out, err = pssd("render", path, "-o", tmp_path / "s.png", "--color", "displacement")
    assert status == 0, err
    import matplotlib.image

    image = matplotlib.image.imread(tmp_path / "s.png")[:, :600, :3]  # without the colour bar
    blue = image[..., 2][image[..., 2] - image[..., 0] > 0.05]  # plasma(0), not the title
    assert blue.size > 10000
    assert np.ptp(blue) > 0.3


def survey_file(path, **fields):
    """A small wide, flat scene (60 x 20, 1 of relief) as ``.npz``, with ``fields``."""
    rng = np.random.default_rng(4)
    u, v = rng.uniform(0, 60, 3000), rng.uniform(0, 20, 3000)
    points = np.column_stack([u, v, 0.5 * np.sin(u / 6.0) + 0.5 * v / 20.0])
    np.savez(path, points=points, **{k: f(points) for k, f in fields.items()})
    return path


SURVEY_FIELDS = {
    "classification": lambda p: np.where(p[:, 0] < 30, 2, 6).astype(np.uint8),
    "intensity": lambda p: (p[:, 1] * 3000).astype(np.uint16),
    "red": lambda p: np.full(len(p), 200 * 257, np.uint16),
    "green": lambda p: np.full(len(p), 40 * 257, np.uint16),
    "blue": lambda p: np.full(len(p), 40 * 257, np.uint16),
}


@pytest.mark.parametrize("color", ["classification", "intensity", "rgb"])
def test_render_colours_a_survey_by_its_own_fields(tmp_path, color):
    import matplotlib.image

    path = survey_file(tmp_path / "survey.npz", **SURVEY_FIELDS)
    status, out, err = pssd("render", path, "-o", tmp_path / "s.png", "--color", color)
    assert status == 0, err
    assert "(up axis z, view 50 " in out  # flat: seen as a scene
    image = np.rint(matplotlib.image.imread(tmp_path / "s.png")[..., :3] * 255).astype(int)
    assert image.shape[0] < 0.6 * image.shape[1]  # a wide picture for a wide scene
    pixels = image[(image < 255).any(axis=-1)]
    spread = np.ptp(pixels, axis=1)  # 0 for greys (and the black text)
    if color == "intensity":
        assert (spread <= 1).mean() > 0.99
    else:  # red (rgb), or earth and red (classes): shaded, never grey
        assert (spread > 60).mean() > 0.5


def test_render_offers_every_colouring_of_the_pictures():
    from pssd_fast import pictures

    assert cli.COLORS == pictures.COLOR_FIELDS


def test_render_of_a_field_the_file_lacks_names_what_it_has(tmp_path):
    path = survey_file(tmp_path / "survey.npz", intensity=SURVEY_FIELDS["intensity"])
    status, _, err = pssd("render", path, "-o", tmp_path / "s.png", "--color", "classification")
    assert_one_line_error(status, err, f"{path}: the cloud holds no classification; colour it by "
                          "height, curvature, likelihood, feature, intensity (its per-point "
                          "fields: intensity)")
    assert not (tmp_path / "s.png").exists()
    status, _, err = pssd("render", path, "-o", tmp_path / "s.png", "--color", "rgb")
    assert_one_line_error(status, err, "holds no red, green and blue; colour it by")


def test_render_names_a_las_file_s_units_on_the_colour_bar(tmp_path, monkeypatch):
    from pssd_fast.pictures import draw

    wkt = ('PROJCS["x",GEOGCS["g",UNIT["degree",0.0174532925199433]],'
           'UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]]')
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(wkt))
    header.scales = (0.01, 0.01, 0.01)
    las = laspy.LasData(header)
    rng = np.random.default_rng(5)
    las.x, las.y, las.z = rng.uniform(0, 200, 2000), rng.uniform(0, 80, 2000), \
        rng.uniform(0, 2, 2000)
    las.write(tmp_path / "ft.las")
    seen = []
    render = draw.render
    monkeypatch.setattr(draw, "render", lambda *a, **kw: seen.append(kw) or render(*a, **kw))
    status, _, err = pssd("render", tmp_path / "ft.las", "-o", tmp_path / "ft.png")
    assert status == 0, err
    assert seen[0]["units"] == "ft" and seen[0]["field"] == "height"


def test_the_summary_reports_the_method_s_moves_in_memory_as_out_of_core(tmp_path):
    """The summary's moves are the method's, in memory as out of core: the same numbers; for
    a LAS output it says that the format then rounds the coordinates to its scale."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = (0.01, 0.01, 0.01)
    las = laspy.LasData(header)
    cloud = datasets.cad_part(n_points=3000, noise=0.01, seed=2)
    las.x, las.y, las.z = (cloud.points * 10.0).T
    las.write(tmp_path / "in.las")
    status, out, err = pssd("denoise", tmp_path / "in.las", tmp_path / "out.npy")
    assert status == 0, err
    before = laspy.read(tmp_path / "in.las")
    moves = np.linalg.norm(np.load(tmp_path / "out.npy") - before.xyz, axis=1)
    summary = r"displacement max (\S+), mean (\S+)"
    found = re.search(summary + "$", out.strip())
    assert found, out
    assert float(found[1]) == pytest.approx(moves.max(), rel=1e-3)
    assert float(found[2]) == pytest.approx(moves.mean(), rel=1e-3)
    rounded = summary + r" \(before the format rounds the coordinates to its scale\)"
    for extra in ([], ["--tile-points", "1000"]):
        status, out, err = pssd("denoise", tmp_path / "in.las", tmp_path / "out.las", "--force",
                                *extra)
        assert status == 0, err
        assert re.search(rounded, out)[0] == f"{found[0]} (before the format rounds the " \
                                             f"coordinates to its scale)", out


@pytest.mark.parametrize("extra, named", [([], "method robust, preset default"),
                                          (["--preset", "fast"], "method robust, preset fast"),
                                          (["--method", "mls"], "method mls"),
                                          (["--tile-points", "1000"],
                                           "method robust, preset default")])
def test_the_summary_names_the_preset_that_the_stats_name(tmp_path, extra, named):
    """The summary names the method and, for the robust method, the preset, which is what
    ``stats["plan"]["method"]`` calls the run (in memory and out of core)."""
    np.save(tmp_path / "in.npy", datasets.cad_part(n_points=2000, noise=0.005, seed=1).points)
    status, out, err = pssd("denoise", tmp_path / "in.npy", tmp_path / "out.npy", *extra)
    assert status == 0, err
    assert f" points, {named}, " in out, out


@pytest.mark.parametrize("classes", [None, "6"])
def test_render_draws_the_points_of_other_classes_grey(tmp_path, monkeypatch, classes):
    """The displacement of a classified file (as pssd denoise --fields displacement writes it)
    is drawn grey, with a legend entry, for the points of the classes pssd denoise kept in
    place: by default the surface classes' others, else those --classes names."""
    from pssd_fast.pictures import draw

    fields = {"classification": lambda p: np.where(p[:, 0] < 20, 2,
                                                   np.where(p[:, 0] < 40, 6, 5)).astype(np.uint8)}
    path = survey_file(tmp_path / "survey.npz", **fields)
    more = () if classes is None else ("--classes", classes)
    status, _, err = pssd("denoise", path, tmp_path / "out.npz", "--fields", "displacement",
                          *more)
    assert status == 0, err
    seen = []
    render = draw.render
    monkeypatch.setattr(draw, "render", lambda *a, **kw: seen.append((a, kw)) or render(*a,
                                                                                       **kw))
    status, _, err = pssd("render", tmp_path / "out.npz", "-o", tmp_path / "d.png", "--color",
                          "displacement", *more)
    assert status == 0, err
    (points, values, _), options = seen[0]
    denoised = (points[:, 0] < 40) if classes is None else (points[:, 0] >= 20) & (
        points[:, 0] < 40)
    np.testing.assert_array_equal(np.isnan(values), ~denoised)
    assert options["missing"] == "kept in place\n(other classes)"
    assert (values[denoised] > 0).any()


def test_fields_not_asked_for_are_not_computed(tmp_path, cloud, monkeypatch):
    """The default method computes its likelihood and feature intensity when they are read:
    pssd denoise reads them only where --fields asks for them."""
    from pssd_fast import executor

    np.savetxt(tmp_path / "in.xyz", cloud.points)

    def unasked(*args):
        raise AssertionError("the feature intensity was computed")

    monkeypatch.setattr(executor, "means_feature", unasked)
    assert cli.main(["denoise", str(tmp_path / "in.xyz"), str(tmp_path / "out.ply"),
                     "--fields", "displacement,held", "--quiet"]) == 0


def test_render_size_takes_a_width_and_an_optional_height(tmp_path):
    import matplotlib.image

    path = survey_file(tmp_path / "survey.npz")
    for size, shape in (([400], None), ([400, 300], (300, 400))):
        status, _, err = pssd("render", path, "-o", tmp_path / "s.png", "--size", *size,
                              "--force")
        assert status == 0, err
        got = matplotlib.image.imread(tmp_path / "s.png").shape[:2]
        assert got == shape if shape else (got[1] == 400 and got[0] < 240)
    assert_one_line_error(*pssd("render", path, "-o", tmp_path / "t.png", "--size", 1, 2,
                                3)[::2], "--size takes WIDTH [HEIGHT]")
    # A picture of 100,000 pixels a side would need 64 GB before a line is drawn.
    assert_one_line_error(*pssd("render", path, "-o", tmp_path / "t.png", "--size", 100_000,
                                100_000)[::2], "width must be at most 8192")


def test_demo_writes_files_and_pictures(tmp_path):
    folder = tmp_path / "demo"
    status, out, err = pssd("demo", "--out", folder, "--points", "3000", "--iterations", "1")
    assert status == 0, err
    assert "| Robust (default) | 1 |" in out
    assert "| Max. displacement (1e-4) | Ave. displacement (1e-4) |" in out and "error" not in out
    names = {p.name for p in folder.iterdir()}
    assert {"noisy.ply", "denoised.ply", "noisy.png", "curvature.png", "likelihood.png",
            "feature.png", "denoised_curvature.png", "denoised_displacement.png"} <= names
    assert_one_line_error(*pssd("demo", "--out", folder, "--points", "3000")[::2], "--force")


@pytest.mark.parametrize("args, match", [
    (["denoise", "missing.ply", "out.ply"], "missing.ply"),
    (["denoise", "in.xyz", "out.ply", "--method", "mls", "--radius-factor", "3"],
     "--radius-factor is not a parameter of method 'mls'"),
    (["denoise", "in.xyz", "out.ply", "--method", "mls", "--lam", "0.5"],
     "lam only applies to the robust method; method 'mls' does not use it"),
    (["denoise", "in.xyz", "out.ply", "--method", "bilateral", "--h", "0.1"],
     "--h is not a parameter of method 'bilateral'"),
    (["denoise", "in.xyz", "out.ply", "--h", "0.1"], "h only applies to the paper's pipeline"),
    (["denoise", "in.xyz", "out.ply", "--preset", "paper", "--sigma-n", "0.1"],
     "--sigma-n only applies to the default method (presets 'default' and 'fast')"),
    (["denoise", "in.xyz", "out.unknown"], "unknown"),
    (["denoise", "in.xyz", "out.ply", "--k", "5"], "k must be at least 10"),
    (["denoise", "five.xyz", "out.ply"], "the cloud has 5 points; denoising needs at least 11"),
    (["denoise", "in.xyz", "out.ply", "--duplicate-tolerance", "-1"],
     "--duplicate-tolerance must be a finite distance of at least 0"),
    (["denoise", "in.xyz", "nowhere/out.ply"], "does not exist"),
    (["info", "truncated.ply"], "truncated.ply"),
    (["info", "malformed.xyz"], "malformed.xyz"),
    (["info", "truncated.las"], "truncated.las"),
    (["denoise", "in.xyz", "in.xyz/out.ply"], "is not a folder"),
    (["denoise", "in.xyz", "./in.xyz"], "in.xyz is the input file; choose another output"),
    (["denoise", "in.xyz", "in.xyz", "--force"], "is the input file; choose another output"),
    (["info", "."], ".: is a directory, not a point-cloud file"),
    (["denoise", ".", "o.ply"], ".: is a directory, not a point-cloud file"),
    (["denoise", "in.xyz", "."], ".: is a directory, not a file name"),
])
def test_errors_are_one_line(tmp_path, cloud, args, match):
    np.savetxt(tmp_path / "in.xyz", cloud.points)
    np.savetxt(tmp_path / "five.xyz", cloud.points[:5])
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

    def full_disk(call):
        """``call`` (the rename or the link that gives the output its name) failing on it."""
        def failing(src, dst):
            if str(dst).endswith("out.ply"):
                raise OSError(errno.ENOSPC, "No space left on device")
            return call(src, dst)
        return failing

    monkeypatch.setattr(os, "replace", full_disk(os.replace))
    monkeypatch.setattr(os, "link", full_disk(os.link))
    status = cli.main(["denoise", str(source), str(tmp_path / "out.ply"), "--iterations", "1",
                       "--quiet"])
    err = capsys.readouterr().err
    assert_one_line_error(status, err, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.xyz"]
    assert source.read_bytes() == before


def test_sigterm_while_writing_leaves_nothing(tmp_path, cloud):
    """SIGTERM is handled like Ctrl-C: one line, status 143, no temporary file left."""
    import os
    import signal
    import time

    source = tmp_path / "in.npy"
    np.save(source, cloud.points)
    # The child holds the write open (before its fsync) until it is terminated, so that the
    # signal arrives while the temporary file exists, whatever the machine's speed.
    child = ("import os, sys, time; os.fsync = lambda fd: time.sleep(600); "
             "from pssd_fast import cli; sys.exit(cli.main(sys.argv[1:]))")
    proc = subprocess.Popen([sys.executable, "-c", child, "denoise", str(source),
                             str(tmp_path / "out.ply"), "--iterations", "1", "--quiet"],
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not list(tmp_path.glob(".out.*.partial.ply")):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=60)[1]
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines() == ["pssd: terminated"], err
    assert sorted(os.listdir(tmp_path)) == ["in.npy"]


def test_sigma_n_reaches_the_library(tmp_path, cloud):
    source, out = tmp_path / "in.npy", tmp_path / "out.npz"
    np.save(source, cloud.points)
    assert cli.main(["denoise", str(source), str(out), "--iterations", "1", "--sigma-n", "0.3",
                     "--quiet"]) == 0
    expected = pssd_fast.denoise(cloud.points, iterations=1, sigma_n=0.3)
    np.testing.assert_array_equal(np.load(out)["points"], expected.points)


def test_threads_is_n_jobs(tmp_path, cloud):
    source = tmp_path / "in.npy"
    np.save(source, cloud.points)
    status, out, err = pssd("denoise", source, tmp_path / "out.npy", "--preset", "paper",
                            "--iterations", "1", "--threads", "1", "--verbose")
    assert status == 0, err
    assert "k = 25; 1 thread\n" in out


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


@pytest.mark.parametrize("flags, shift", [((), True), (("--no-shift-normals",), False)])
def test_shifted_normals_reach_the_library(tmp_path, cloud, flags, shift):
    source, out = tmp_path / "in.npy", tmp_path / "out.npz"
    np.save(source, cloud.points)
    status = cli.main(["denoise", str(source), str(out), "--iterations", "1", *flags,
                       "--quiet"])
    assert status == 0
    expected = pssd_fast.denoise(cloud.points, iterations=1, shift_normals=shift)
    np.testing.assert_array_equal(np.load(out)["points"], expected.points)
    other = pssd_fast.denoise(cloud.points, iterations=1, shift_normals=not shift)
    assert np.abs(other.points - expected.points).max() > 0  # the flag changes the result


def test_no_shift_normals_is_refused_by_the_paper_preset(tmp_path, cloud, capsys):
    source = tmp_path / "in.npy"
    np.save(source, cloud.points)
    status = cli.main(["denoise", str(source), str(tmp_path / "out.npy"), "--preset", "paper",
                       "--no-shift-normals"])
    assert status == 1
    assert "shift_normals only applies to the default method" in capsys.readouterr().err


def test_an_unwritable_folder_is_one_line(tmp_path, cloud, monkeypatch, capsys):
    """Root ignores permission bits, so the refusal is simulated where the file is created."""
    import builtins

    from pssd_fast import atomic

    source = tmp_path / "in.xyz"
    np.savetxt(source, cloud.points)

    def refuse(file, mode="r", *args, **kwargs):
        if "x" in mode:
            raise PermissionError(13, "Permission denied", str(file))
        return builtins.open(file, mode, *args, **kwargs)

    monkeypatch.setattr(atomic, "open", refuse, raising=False)  # the temporary's open
    status = cli.main(["denoise", str(source), str(tmp_path / "out.ply"), "--iterations", "1",
                       "--quiet"])
    assert_one_line_error(status, capsys.readouterr().err, "Permission denied")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.xyz"]


def test_a_read_only_folder_is_refused_before_the_input_is_read(tmp_path, cloud, monkeypatch,
                                                                capsys):
    """The output folder is tried (a temporary of the writer's kind, removed) before any work;
    root ignores permission bits, so the refusal is simulated where that file is created."""
    source = tmp_path / "in.xyz"
    np.savetxt(source, cloud.points)
    folder = tmp_path / "rodir"
    folder.mkdir()

    def unread(*args, **kwargs):
        raise AssertionError("the input was read")

    refuse_new_files(monkeypatch)
    monkeypatch.setattr(cli, "_read", unread)
    for args in ([str(source), str(folder / "out.laz")], [str(source), "-o", str(folder)]):
        status = cli.main(["denoise", *args, "--quiet"])
        assert_one_line_error(status, capsys.readouterr().err,
                              f"output folder {folder} is not writable (Permission denied)")
    monkeypatch.undo()
    status = cli.main(["denoise", str(source), str(folder / "out.ply"), "--iterations", "1",
                       "--quiet"])
    assert status == 0 and sorted(p.name for p in folder.iterdir()) == ["out.ply"]


@pytest.mark.parametrize("preset, iterations", [("default", method.ITERATIONS), ("paper", 2)])
def test_quick_start_demo_reports_the_preset(capsys, preset, iterations):
    from pssd_fast.__main__ import main

    assert main(["--points", "3000", "--preset", preset]) == 0
    out = capsys.readouterr().out
    assert f"preset '{preset}': {iterations} iterations" in out
    assert "within 1% of a sharp edge, mean" in out


def test_main_runs_outside_the_main_thread(tmp_path, capsys):
    """Tools may call the CLI from a worker thread, where no signal handler can be set."""
    import threading
    path = tmp_path / "cloud.npy"
    np.save(path, np.random.default_rng(0).random((50, 3)))
    status = []
    worker = threading.Thread(target=lambda: status.append(cli.main(["info", str(path)])))
    worker.start()
    worker.join()
    assert status == [0]
    assert "50" in capsys.readouterr().out


# ---------------------------------------------------------------------------------------------
# Formats, stdin/stdout, batches and the added fields


@pytest.fixture(scope="module")
def small():
    return datasets.cad_part(n_points=800, noise=0.003, seed=2).points


def csv_lines(points, header="//X,Y,Z,R,G,B"):
    rgb = np.arange(3 * len(points)).reshape(-1, 3) % 256
    rows = [",".join([*map(repr, map(float, p)), *map(str, c)]) for p, c in zip(points, rgb)]
    return [header, *rows], rgb


def test_xyzrgb_keeps_its_colours(tmp_path, small):
    """Six unnamed columns with integer colours, a black point among them: the colours come
    out byte for byte, the coordinates moved, and a note says how the columns were read."""
    lines, rgb = csv_lines(small, header=None)
    lines = [line.replace(",", " ") for line in lines[1:]]
    lines[0] = " ".join(lines[0].split()[:3] + ["0", "0", "0"])
    (tmp_path / "six.xyz").write_text("\n".join(lines) + "\n")
    status, text, err = pssd("denoise", tmp_path / "six.xyz", tmp_path / "out.xyz",
                             "--iterations", "1")
    assert status == 0, err
    assert err.strip() == (f"pssd: note: {tmp_path / 'six.xyz'}: no column names; columns 4-6 "
                           "read as red, green, blue (integers); name the columns to read them "
                           "otherwise (columns=, --columns)")
    out = (tmp_path / "out.xyz").read_text().splitlines()
    rows = [line.split() for line in out if not line.startswith("#")]
    assert [row[3:6] for row in rows] == [line.split()[3:] for line in lines]
    moved = np.array([row[:3] for row in rows], dtype=float)
    assert (np.abs(moved - small).max(axis=1) > 0).mean() > 0.9


def test_columns_option_names_text_columns(tmp_path, small):
    """``--columns`` names the columns of a file without names, and wins over a wrong header;
    a file of another format refuses it."""
    lines, rgb = csv_lines(small, header="x,y,z,nx,ny,nz")
    (tmp_path / "in.csv").write_text("\n".join(lines) + "\n")
    status, _, err = pssd("info", tmp_path / "in.csv", "--columns", "x,y,z,r,g,b")
    assert status == 0 and "replace those of header line 1 (x, y, z, nx, ny, nz)" in err
    status, _, err = pssd("denoise", tmp_path / "in.csv", tmp_path / "out.csv", "--iterations",
                          "1", "--columns", "x,y,z,red,green,blue", "--fields", "none")
    assert status == 0, err
    out = (tmp_path / "out.csv").read_text().splitlines()
    assert out[0] == "x,y,z,red,green,blue"
    assert [row.split(",")[3:] for row in out[1:]] == [list(map(str, c)) for c in rgb]
    np.save(tmp_path / "in.npy", small)
    status, _, err = pssd("denoise", tmp_path / "in.npy", tmp_path / "o.npy", "--columns",
                          "x,y,z")
    assert_one_line_error(status, err, "columns= names the columns of text files")
    status, _, err = pssd("info", tmp_path / "in.csv", "--columns", "x,y")
    assert_one_line_error(status, err, "the column list x,y names 2 columns but the data has 6")


class Stdio:
    """Stands for sys.stdin / sys.stdout in-process: the data goes through ``buffer``."""

    def __init__(self, data=b""):
        import io

        self.buffer = io.BytesIO(data)

    def write(self, text):  # text written to stdout by mistake would land here
        self.buffer.write(text.encode())


def test_stdin_to_stdout_in_a_subprocess(small):
    data = "\n".join(" ".join(map(repr, map(float, p))) for p in small) + "\n"
    done = subprocess.run([sys.executable, "-m", "pssd_fast.cli", "denoise", "-", "-",
                           "--format", "xyz", "--iterations", "1"], input=data.encode(),
                          capture_output=True, timeout=600)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.decode().splitlines()
    assert lines[0] == "# x y z" and len(lines) == len(small) + 1
    assert "- -> -: 800 points" in done.stderr.decode()


def test_a_reader_that_stops_early_is_no_error(tmp_path, small):
    """``pssd info f | head -1``: output into a pipe whose reader has gone is no error; the
    command stops quietly with status 0, not with 'Broken pipe'."""
    path = tmp_path / "small.xyz"
    np.savetxt(path, small)
    read, write = os.pipe()
    os.close(read)  # the reader has gone before the first line
    try:
        done = subprocess.run([sys.executable, "-m", "pssd_fast.cli", "info", str(path)],
                              stdout=write, stderr=subprocess.PIPE, timeout=600)
    finally:
        os.close(write)
    err = done.stderr.decode()
    assert done.returncode == 0, err
    assert "Broken pipe" not in err and "Traceback" not in err


class Leaving:
    """A pipe's end whose reader takes the first 100 bytes and goes away: a large write is
    taken in part (its count says how much), the next one raises, as the system's pipe."""

    def __init__(self):
        self.taken = b""

    def write(self, data):
        if self.taken:
            raise BrokenPipeError(32, "Broken pipe")
        self.taken = bytes(data[:100])
        return len(self.taken)

    def flush(self):
        pass


def test_data_cut_short_on_stdout_is_an_error(tmp_path, small, monkeypatch, capsys):
    """The reader of the denoised cloud went away part way: the command fails, rather than
    saying it wrote the cloud and exiting 0."""
    np.savetxt(tmp_path / "small.xyz", small)
    out = Stdio()
    out.buffer = Leaving()
    monkeypatch.setattr(sys, "stdout", out)
    status = cli.main(["denoise", str(tmp_path / "small.xyz"), "-", "--format", "xyz",
                       "--iterations", "1"])
    assert_one_line_error(status, capsys.readouterr().err, "Broken pipe")
    assert len(out.buffer.taken) == 100


def test_stdin_csv_to_stdout_ply_in_process(small, monkeypatch, capsys):
    lines, rgb = csv_lines(small)
    monkeypatch.setattr(sys, "stdin", Stdio("\n".join(lines).encode()))
    out = Stdio()
    monkeypatch.setattr(sys, "stdout", out)
    status = cli.main(["denoise", "-", "-", "--format", "csv", "--iterations", "1",
                       "--verbose", "--fields", "all"])
    err = capsys.readouterr().err
    assert status == 0, err
    assert "iteration 1:" in err and "- -> -" in err  # messages on stderr, data on stdout
    lines = out.buffer.getvalue().decode().splitlines()
    assert lines[0] == ("x,y,z,nx,ny,nz,red,green,blue,likelihood,feature_intensity,"
                        "displacement,outlier_score,held")
    assert [row.split(",")[6:9] for row in lines[1:3]] == [list(map(str, c)) for c in rgb[:2]]


def test_an_error_on_one_input_names_it_as_in_a_batch(tmp_path, capsys):
    np.savetxt(tmp_path / "five.xyz", np.random.default_rng(0).normal(size=(5, 3)))
    status = cli.main(["denoise", str(tmp_path / "five.xyz"), str(tmp_path / "out.xyz")])
    assert_one_line_error(status, capsys.readouterr().err,
                          f"{tmp_path / 'five.xyz'}: the cloud has 5 points")


def test_a_float32_file_far_from_the_origin_gets_the_api_s_note(tmp_path, capsys):
    """The file's float32 coordinates, read as float64, warn as a float32 array does."""
    points = datasets.cad_part(n_points=3000, noise=0.003, seed=1).points * 100
    np.save(tmp_path / "far.npy", (points + [4.5e5, 4e6, 100.0]).astype(np.float32))
    np.save(tmp_path / "near.npy", points.astype(np.float32))
    for name, noted in (("far.npy", True), ("near.npy", False)):
        assert cli.main(["denoise", str(tmp_path / name), str(tmp_path / "out.npy"), "--quiet",
                         "--force"]) == 0
        err = capsys.readouterr().err
        assert ("pssd: note: points are float32 and reach 4000" in err) == noted, err


def test_info_reads_stdin_with_a_format(small, monkeypatch, capsys):
    lines, _ = csv_lines(small)
    monkeypatch.setattr(sys, "stdin", Stdio("\n".join(lines).encode()))
    status = cli.main(["info", "-", "--format", "csv"])
    out, err = capsys.readouterr()
    assert status == 0, err
    assert out.startswith(f"-: xyz, {len(small):,} points\n") and "red (uint8)" in out
    for command in (["info", "-"], ["render", "-", "-o", "picture.png"]):  # render too
        assert_one_line_error(cli.main(command), capsys.readouterr().err,
                              "'-' needs a format (format='xyz', --format xyz")


def test_dash_needs_a_format(tmp_path, capsys):
    status = cli.main(["denoise", "-", str(tmp_path / "out.ply")])
    assert_one_line_error(status, capsys.readouterr().err, "'-' needs --format")
    # And --format is for '-' alone: with two named files it used to be ignored unsaid.
    status = cli.main(["denoise", str(tmp_path / "in.xyz"), str(tmp_path / "out.ply"),
                       "--format", "xyz"])
    assert_one_line_error(status, capsys.readouterr().err,
                          "--format names the format of '-' (stdin or stdout) only")


def test_batch_into_a_folder(tmp_path, small):
    lines, rgb = csv_lines(small)
    (tmp_path / "a.csv").write_text("\n".join(lines) + "\n")
    np.savetxt(tmp_path / "b.xyz", small)
    out = tmp_path / "out" / "deeper"
    status, stdout, err = pssd("denoise", tmp_path / "a.csv", tmp_path / "b.xyz", "-o", out,
                               "--iterations", "1", "--fields", "displacement")
    assert status == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["a.csv", "b.xyz"]
    assert stdout.count(" -> ") == 2
    a = (out / "a.csv").read_text().splitlines()
    assert a[0] == "x,y,z,red,green,blue,displacement"  # the input had no normals
    assert a[1].split(",")[3:6] == list(map(str, rgb[0]))  # integers stay integers
    # The same names again need --force; two inputs of one name are refused before any work.
    assert_one_line_error(*pssd("denoise", tmp_path / "b.xyz", "-o", out)[::2], "--force")
    (tmp_path / "sub").mkdir()
    np.savetxt(tmp_path / "sub" / "b.xyz", small)
    assert_one_line_error(*pssd("denoise", tmp_path / "b.xyz", tmp_path / "sub" / "b.xyz", "-o",
                                tmp_path / "other")[::2], "as b.xyz")
    assert not (tmp_path / "other").exists()
    assert_one_line_error(*pssd("denoise", tmp_path / "b.xyz", tmp_path / "a.csv",
                                tmp_path / "c.ply")[::2], "IN [IN ...] -o FOLDER")


def test_fields_choose_what_is_added(tmp_path, small, capsys):
    np.savetxt(tmp_path / "in.xyz", small)
    base = ["denoise", str(tmp_path / "in.xyz"), "--iterations", "1", "--quiet"]
    assert cli.main([*base[:2], str(tmp_path / "none.las"), *base[2:], "--fields", "none"]) == 0
    assert cli.main([*base[:2], str(tmp_path / "default.las"), *base[2:]]) == 0
    assert cli.main([*base[:2], str(tmp_path / "some.las"), *base[2:], "--fields",
                     "Displacement,NORMALS"]) == 0  # as column names elsewhere, in any case
    assert cli.main([*base[:2], str(tmp_path / "all.las"), *base[2:], "--fields", "all"]) == 0
    dims = {name: list(laspy.read(tmp_path / f"{name}.las").point_format.extra_dimension_names)
            for name in ("none", "default", "some", "all")}
    assert dims == {"none": [], "default": [], "some": ["displacement", "nx", "ny", "nz"],
                    "all": ["likelihood", "feature_intensity", "displacement", "outlier_score",
                            "held", "nx", "ny", "nz"]}
    las = laspy.read(tmp_path / "all.las")
    assert {las[d].dtype for d in dims["all"] if d != "held"} == {np.dtype(np.float32)}
    assert las["held"].dtype == np.uint8
    # .npy holds points only: all adds nothing, and says nothing.
    assert cli.main([*base[:2], str(tmp_path / "out.npy"), *base[2:], "--fields", "all"]) == 0
    assert np.load(tmp_path / "out.npy").shape == (len(small), 3)
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("name, extra, match", [
    ("out.ply", ["--fields", "likelihood,color"], "unknown field(s) color; choose from "
     "likelihood, feature_intensity, displacement, outlier_score, normals, held, all or none"),
    ("out.ply", ["--fields", "likelihood", "--method", "mls"],
     "method 'mls' computes no likelihood"),
    ("out.npy", ["--fields", "likelihood"], "out.npy cannot hold likelihood"),
    ("out.ply", ["--fields", "all,none"], "--fields: all and none stand alone; got 'all,none'"),
    ("out.ply", ["--fields", "likelihood,all"], "all and none stand alone"),
])
def test_fields_errors(tmp_path, small, capsys, name, extra, match):
    np.savetxt(tmp_path / "in.xyz", small)
    status = cli.main(["denoise", str(tmp_path / "in.xyz"), str(tmp_path / name),
                       "--iterations", "1", "--quiet", *extra])
    assert_one_line_error(status, capsys.readouterr().err, match)
    assert not (tmp_path / name).exists()


def test_normals_asked_of_an_npy_output_are_refused(tmp_path, capsys):
    """An .npy output holds the points only (unless the input was an (n, 6) .npy): --fields
    normals is refused as the fields it cannot hold are, and all leaves them out."""
    path = tmp_path / "in.xyz"
    np.savetxt(path, datasets.cad_part(n_points=600, noise=0.004, seed=1).points)
    status = cli.main(["denoise", str(path), str(tmp_path / "out.npy"), "--fields", "normals",
                       "--quiet"])
    assert_one_line_error(status, capsys.readouterr().err,
                          "out.npy cannot hold normals (use .npz")
    assert not (tmp_path / "out.npy").exists()
    assert cli.main(["denoise", str(path), str(tmp_path / "out.npy"), "--fields", "all",
                     "--quiet"]) == 0
    assert capsys.readouterr().err == "" and np.load(tmp_path / "out.npy").shape == (600, 3)


def test_dropped_attributes_are_a_one_line_note(tmp_path, ply_with_extras, capsys):
    path, _ = ply_with_extras
    status = cli.main(["denoise", str(path), str(tmp_path / "out.npy"), "--iterations", "1",
                       "--quiet"])
    err = capsys.readouterr().err
    assert status == 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pssd: note: ") and \
        "cannot hold fields ['red', 'green', 'blue', 'quality']" in lines[0], err
    assert "warn" not in err.lower()


def test_obj_and_gzip_end_to_end(tmp_path, small, capsys):
    faces = "\n".join(f"f {i + 1} {i + 2} {i + 3}" for i in range(3))
    body = "\n".join("v " + " ".join(map(repr, map(float, p))) for p in small)
    with gzip.open(tmp_path / "scan.obj.gz", "wt") as fh:
        fh.write(f"o scan\n{body}\n{faces}\n")
    assert cli.main(["denoise", str(tmp_path / "scan.obj.gz"), str(tmp_path / "clean.obj.gz"),
                     "--iterations", "1", "--quiet"]) == 0
    with gzip.open(tmp_path / "clean.obj.gz", "rt") as fh:
        lines = fh.read().splitlines()
    assert lines[0] == "o scan" and lines[-3:] == faces.splitlines()
    assert sum(line.startswith("v ") for line in lines) == len(small)
    assert not any(line.startswith("vn ") for line in lines)  # the input had no normals
    assert capsys.readouterr().err == ""


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
                             "--remove-outliers", "--fields", "normals,outlier_score")
    assert status == 0, err
    after = laspy.read(str(out))
    assert (np.asarray(after["nz"]) > 0).all()
    kept = np.asarray(after.intensity).astype(np.int64)
    assert 4000 - 20 <= len(kept) < 4040 and (kept >= 4000).sum() <= 4
    assert np.asarray(after["outlier_score"]).dtype == np.float32
    assert (np.asarray(after["outlier_score"]) <= 1).all()
    assert "outliers removed" in text
    status, _, err = pssd("denoise", tmp_path / "scan.las", tmp_path / "all.las",
                          "--preset", "fast", "--orient", "0,0,-1000", "--fields", "normals")
    assert status == 0, err
    every = laspy.read(str(tmp_path / "all.las"))
    # The terrain faces the viewpoint below it; the 40 scattered points have no surface.
    assert len(every.x) == 4040 and (np.asarray(every["nz"])[:4000] < 0).all()


def test_outlier_query_only_when_its_field_is_asked_for(tmp_path, monkeypatch):
    """``--fields none`` (or fields without it) makes no outlier query; ``outlier_score`` is
    that of the input points, and ``--verbose`` gives its time beside the stages'."""
    _terrain_las(tmp_path / "scan.las")

    def no_query(*args, **kwargs):
        raise AssertionError("an outlier query ran")

    with monkeypatch.context() as patch:
        patch.setattr(pssd_fast.core, "outlier_score", no_query)
        for fields in ("none", "displacement,normals"):
            status, text, err = pssd("denoise", tmp_path / "scan.las", tmp_path / "out.las",
                                     "--preset", "fast", "--fields", fields, "--verbose",
                                     "--force")
            assert status == 0, err
            assert "iteration 2:" in text and "outlier score" not in text
    status, text, err = pssd("denoise", tmp_path / "scan.las", tmp_path / "score.las",
                             "--preset", "fast", "--fields", "outlier_score", "--verbose")
    assert status == 0, err
    assert "outlier score: " in text
    points = pssd_fast.io.read(tmp_path / "scan.las").points
    np.testing.assert_array_equal(laspy.read(tmp_path / "score.las")["outlier_score"],
                                  pssd_fast.outlier_score(points).astype(np.float32))


def test_orient_and_removal_errors(tmp_path, ply_with_extras):
    path, _ = ply_with_extras
    # The faces of the outliers removed go with them, with a note.
    status, _, err = pssd("denoise", path, tmp_path / "out.ply", "--remove-outliers",
                          "--iterations", "1", "--quiet")
    assert status == 0, err
    assert err == "" or "face rows index dropped vertices and are dropped" in err
    status, _, err = pssd("denoise", path, tmp_path / "out.ply", "--orient", "left")
    assert status == 2 and "expected outward, up or a viewpoint X,Y,Z" in err


def test_verbose_tells_the_plan(tmp_path):
    """The default method's list length, bound and probe, and the refinement's lists; the
    stages of each iteration, the points' own after the last."""
    thick = datasets.cad_part(n_points=6000, noise=0.03, seed=3)
    path = tmp_path / "thick.xyz"
    np.savetxt(path, thick.points)
    status, stdout, err = pssd("denoise", path, tmp_path / "out.xyz", "--verbose")
    assert status == 0, err
    plan = pssd_fast.denoise(thick.points).stats["plan"]
    noise, refine = plan["noise"], plan["refine"]
    assert (f"k = {plan['k']} cell means within {plan['bound']:.4g}, from the probe's noise "
            f"{noise['sigma']:.4g} and spacing {noise['spacing']:.4g} (cells of edge "
            f"{plan['cell_edge']:.4g}); the points that fail the test refit over {refine['k']} "
            f"points within {refine['bound']:.4g}; ") in stdout
    assert "iteration 1: neighbors" in stdout and "project" in stdout
    _assert_summary_then_details(stdout)


def _assert_summary_then_details(text):
    """``--verbose``'s order, in core and out of core: the line of every run, then the plan,
    then the stages of each iteration (out of core between the passes over the file)."""
    lines = text.splitlines()
    assert " -> " in lines[0] and lines[1].startswith("k = "), text
    first = 3 if "out of core" in lines[0] else 2
    assert lines[first].startswith("iteration 1: "), text


def test_tile_points_give_the_in_core_file(tmp_path):
    pytest.importorskip("dask")
    thick = datasets.cad_part(n_points=20000, noise=0.03, seed=3)
    path = tmp_path / "thick.xyz"
    np.savetxt(path, thick.points)
    assert pssd("denoise", path, tmp_path / "in_core.ply", "--preset", "fast")[0] == 0
    status, out, err = pssd("denoise", path, tmp_path / "tiled.ply", "--preset", "fast",
                            "--tile-points", "2000", "--scheduler", "sync")
    assert status == 0, err
    tiles = re.search(r"; (\d+) tiles of at most ([\d,]+) points, in memory; displacement",
                      out)
    assert tiles and int(tiles[1]) >= 10 and int(tiles[2].replace(",", "")) <= 2000, out
    from pssd_fast import io

    in_core = io.read(tmp_path / "in_core.ply")
    tiled = io.read(tmp_path / "tiled.ply")
    np.testing.assert_array_equal(tiled.points, in_core.points)
    np.testing.assert_array_equal(tiled.normals, in_core.normals)
    for name in in_core.fields:
        np.testing.assert_array_equal(tiled.fields[name], in_core.fields[name])


def _near_copies(tmp_path):
    """The generated part with 500 rows again 1e-9 away, saved as ``in.npy``, and its
    in-core result with cubes of 1e-6."""
    points = datasets.cad_part(n_points=2500, noise=0.002, seed=3).points
    near = np.concatenate([points, points[:500] + 1e-9])
    np.save(tmp_path / "in.npy", near)
    want = pssd_fast.denoise(near, iterations=1, duplicate_tolerance=1e-6)
    assert want.stats["duplicates"] > 450
    return want


def test_duplicate_tolerance_reaches_the_library(tmp_path):
    """Rows 1e-9 apart merge in cubes of 1e-6, and the line says how many, as out of core."""
    want = _near_copies(tmp_path)
    status, out, err = pssd("denoise", tmp_path / "in.npy", tmp_path / "out.npy",
                            "--iterations", "1", "--duplicate-tolerance", "1e-6")
    assert status == 0, err
    assert "out of core" not in out
    assert f"({want.stats['duplicates']:,} rows at another row's position, denoised" in out
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), want.points)


def test_duplicate_tolerance_reaches_tiled_runs(tmp_path):
    """Out of core (``--tile-points`` on ``.npy``), the in-core result; ``--verbose`` tells
    the plan and the stage times there as in core."""
    pytest.importorskip("dask")
    want = _near_copies(tmp_path)
    status, out, err = pssd("denoise", tmp_path / "in.npy", tmp_path / "tiled.npy",
                            "--iterations", "1", "--duplicate-tolerance", "1e-6",
                            "--tile-points", "1000", "--scheduler", "sync", "--verbose")
    assert status == 0, err
    assert "out of core" in out
    assert f"({want.stats['duplicates']:,} rows at another row's position, denoised" in out
    assert f"k = {want.stats['k']} cell means within" in out
    lines = out.splitlines()
    assert re.fullmatch(r"the file before: buckets [\d.]+, plan [\d.]+, tiles [\d.]+ \(s\)",
                        lines[2]), out
    assert re.fullmatch(r"iteration 1: neighbors [\d.]+, .*, update [\d.]+, .* \(s\)", lines[3])
    assert re.fullmatch(r"the file after: parts [\d.]+, write [\d.]+ \(s\)", lines[4]), out
    _assert_summary_then_details(out)
    np.testing.assert_array_equal(np.load(tmp_path / "tiled.npy"), want.points)


@pytest.mark.parametrize("ext", [pytest.param(".npy", marks=pytest.mark.slow), ".las"])
def test_tile_points_on_npy_and_las_run_out_of_core_with_the_in_core_file(tmp_path, ext):
    """Points, and for LAS the fields and normals asked for; the normals of LAS input face up
    (one by one on a cloud iterated on its points, which the default is here)."""
    pytest.importorskip("dask")
    if ext == ".las":
        pytest.importorskip("laspy")
    from pssd_fast import io

    cloud = datasets.cad_part(n_points=10000, noise=0.002, seed=3)
    path = tmp_path / f"in{ext}"
    io.write(path, io.PointCloud(cloud.points * 10, None, {}, "npy", None))
    # A LAS file has a classification: here 0 everywhere, one cloud in the tiles as in core.
    fields = ("--fields", "likelihood,displacement,normals") if ext == ".las" else ()
    assert pssd("denoise", path, tmp_path / f"in_core{ext}", *fields)[0] == 0
    status, out, err = pssd("denoise", path, tmp_path / f"tiled{ext}", *fields,
                            "--tile-points", "1500", "--scheduler", "sync")
    assert status == 0, err
    tiles = re.search(r"(\d+) tiles? of at most ([\d,]+) points, out of core", out)
    assert tiles and int(tiles[1]) >= 7 and int(tiles[2].replace(",", "")) <= 1500, out
    in_core, tiled = (io.read(tmp_path / f"{name}{ext}") for name in ("in_core", "tiled"))
    np.testing.assert_array_equal(tiled.points, in_core.points)
    assert sorted(tiled.fields) == sorted(in_core.fields)
    for name in in_core.fields:
        np.testing.assert_array_equal(tiled.fields[name], in_core.fields[name])
    if ext == ".las":
        assert (tiled.normals[:, 2] >= 0).all()
        np.testing.assert_array_equal(np.abs(tiled.normals), np.abs(in_core.normals))


@pytest.mark.slow  # Zarr out of core: tests/test_tiled.py; the CLI's path: the .las case
def test_tile_points_read_and_write_zarr(tmp_path):
    pytest.importorskip("dask")
    zarr = pytest.importorskip("zarr")
    points = datasets.cad_part(n_points=10000, noise=0.002, seed=3).points
    zarr.open_array(str(tmp_path / "in.zarr"), mode="w", shape=points.shape,
                    dtype=points.dtype, chunks=(5000, 3))[:] = points
    status, out, err = pssd("denoise", tmp_path / "in.zarr", tmp_path / "out.zarr",
                            "--tile-points", "1500")
    assert status == 0 and "out of core" in out, err
    np.testing.assert_array_equal(zarr.open_array(str(tmp_path / "out.zarr"))[:],
                                  pssd_fast.denoise(points).points)


@pytest.mark.parametrize("extra, match", [
    (("--k", "30"), "does not take --k"),
    (("--preset", "paper"), "does not take --preset paper"),
    (("--method", "mls"), "does not take --method"),
    (("--keep-normals",), "does not take --keep-normals"),
    (("--no-shift-normals",), "does not take --no-shift-normals"),
])
def test_tile_points_name_what_they_do_not_take(tmp_path, small, extra, match):
    path = tmp_path / "small.xyz"
    np.savetxt(path, small)
    status, _, err = pssd("denoise", path, tmp_path / "out.xyz", "--tile-points", "1000",
                          *extra)
    assert status == 1 and match in err


def test_tile_points_remove_outliers_in_memory_but_not_out_of_core(tmp_path, small):
    """In memory the tiles give the in-core file with the outliers dropped; out of core, where
    the output keeps the input's rows, the option is refused before any work."""
    path = tmp_path / "small.xyz"
    np.savetxt(path, small)
    for name, tiles in (("tiled.xyz", ("--tile-points", "500")), ("whole.xyz", ())):
        status, _, err = pssd("denoise", path, tmp_path / name, "--remove-outliers", "--quiet",
                              *tiles)
        assert status == 0, err
    assert (tmp_path / "tiled.xyz").read_text() == (tmp_path / "whole.xyz").read_text()
    np.save(tmp_path / "small.npy", small)
    status, _, err = pssd("denoise", tmp_path / "small.npy", tmp_path / "out.npy",
                          "--tile-points", "500", "--remove-outliers")
    assert_one_line_error(status, err, "--remove-outliers drops rows, which a run out of core")
    assert not (tmp_path / "out.npy").exists()


def test_batch_names_each_output_that_exists_and_writes_the_others(tmp_path, small):
    names = ("a.xyz", "b.xyz", "c.xyz")
    for name in names:
        np.savetxt(tmp_path / name, small)
    out = tmp_path / "out"
    out.mkdir()
    for name in ("a.xyz", "c.xyz"):
        (out / name).write_text("kept\n")
    status, stdout, err = pssd("denoise", *(tmp_path / name for name in names), "-o", out,
                               "--iterations", "1")
    lines = err.strip().splitlines()
    assert status == 1 and len(lines) == 2, err
    for line, name in zip(lines, ("a.xyz", "c.xyz")):
        assert line.startswith("pssd: error: ") and f"{out / name} exists; pass --force" in line
        assert (out / name).read_text() == "kept\n"
    assert stdout.count(" -> ") == 1 and (out / "b.xyz").exists()


@pytest.mark.parametrize("extra, match, python", [
    (("--lam", "0.5"), "--lam only applies to the paper's pipeline; pass --preset paper",
     "preset='paper'"),
    (("--n-jobs", "0"), "--n-jobs must be a positive integer or -1 (all cores)", "None"),
    (("--sigma-n", "0"), "--sigma-n must be positive", "sigma_n"),
    (("--duplicate-tolerance", "-1"), "--duplicate-tolerance", "duplicate_tolerance"),
])
def test_errors_name_the_options_of_the_command_line(tmp_path, small, extra, match, python):
    """The library's messages name its keywords; the command line's name its options."""
    path = tmp_path / "small.xyz"
    np.savetxt(path, small)
    status, _, err = pssd("denoise", path, tmp_path / "out.xyz", *extra)
    assert_one_line_error(status, err, match)
    assert python not in err


def test_a_mistyped_option_shows_its_command_s_usage(capsys):
    with pytest.raises(SystemExit) as stopped:
        cli.main(["denoise", "a.xyz", "b.xyz", "--bogus"])
    err = capsys.readouterr().err
    assert stopped.value.code == 2
    assert "usage: pssd denoise" in err
    assert err.strip().splitlines()[-1] == "pssd denoise: error: unrecognized arguments: --bogus"


def test_zarr_needs_tile_points(tmp_path, capsys):
    status = cli.main(["denoise", str(tmp_path / "in.zarr"), str(tmp_path / "out.zarr")])
    assert_one_line_error(status, capsys.readouterr().err, "in.zarr: Zarr arrays are read and "
                          "written out of core only: pass --tile-points")
    (tmp_path / "in.zarr").mkdir()
    assert_one_line_error(cli.main(["info", str(tmp_path / "in.zarr")]),
                          capsys.readouterr().err, "a Zarr array is read by pssd denoise "
                          "--tile-points")


def test_scheduler_needs_tile_points(tmp_path, small):
    path = tmp_path / "small.xyz"
    np.savetxt(path, small)
    status, _, err = pssd("denoise", path, tmp_path / "out.xyz", "--scheduler", "threads")
    assert status == 1 and "--scheduler runs the tiles of --tile-points" in err


def test_an_unknown_scheduler_is_named_as_the_option(tmp_path, small):
    path = tmp_path / "small.xyz"
    np.savetxt(path, small)
    status, _, err = pssd("denoise", path, tmp_path / "out.xyz", "--tile-points", "1000",
                          "--scheduler", "bogus")
    assert status == 2 and ("argument --scheduler: 'bogus' is neither a local scheduler "
                            "(threads, processes, sync) nor a scheduler's address") in err
    assert not (tmp_path / "out.xyz").exists()


@pytest.mark.parametrize("value, match", [
    ("5", "tile_points must be at least 500; got 5 (a smaller tile is mostly the halo"),
    ("5x", "an integer, not '5x'"),
])
def test_tile_points_are_checked_before_the_input_is_read(tmp_path, value, match):
    status, _, err = pssd("denoise", tmp_path / "absent.xyz", tmp_path / "out.xyz",
                          "--tile-points", value)
    assert status == 2 and f"argument --tile-points: {match}" in err


def test_the_survey_is_as_docs_cli_md_gives_it(tmp_path):
    """docs/cli.md on the shared airborne survey: its extent, the input's bytes, the output's
    (within 0.5%: the count follows the denoised coordinates) and the summary line it quotes."""
    from pssd_fast import io

    source = data_file("lidar", "autzen_trim.laz")
    page = (Path(__file__).resolve().parent.parent / "docs" / "cli.md").read_text()
    x, y, z = np.ptp(io.read(source).points, axis=0)
    assert f"The Autzen survey ({x:,.0f} x {y:,.0f} ft, {z:,.0f} ft of relief)" in page
    given = re.search(r"`autzen_trim\.laz`: ([\d,]+) bytes in, ([\d,]+)\s+out", page)
    bytes_in, bytes_out = (int(count.replace(",", "")) for count in given.groups())
    summary = re.search(r"\(`(class 2 denoised, [\d,]+ points of other classes kept)`\)", page)
    status, out, err = pssd("denoise", source, tmp_path / "out.laz")
    assert status == 0, err
    assert source.stat().st_size == bytes_in
    assert abs((tmp_path / "out.laz").stat().st_size / bytes_out - 1) < 0.005
    assert summary[1] in out


def test_ctrl_c_is_one_line_and_status_130(tmp_path, cloud, monkeypatch):
    source = tmp_path / "in.npy"
    np.save(source, cloud.points)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_run_denoise", interrupted)
    status, _, err = pssd("denoise", source, tmp_path / "out.ply", "--quiet")
    assert status == 130 and err.strip().splitlines() == ["pssd: interrupted"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.npy"]


@pytest.mark.parametrize("tile_points", [None, 1000])
def test_orient_is_refused_with_given_normals_in_every_entry(tmp_path, tile_points):
    """One check, one message: ``denoise``, ``tiled.denoise_file`` and ``pssd denoise`` (in
    core and tiled) refuse to orient normals the input gives, naming whose they are."""
    if tile_points:
        pytest.importorskip("dask")
    cloud = datasets.cad_part(n_points=2000, noise=0.002, seed=4)
    points = np.array(cloud.points)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    source = tmp_path / "with.las"
    pssd_fast.io.write(source, pssd_fast.io.PointCloud(points, normals))
    want = "orient applies to estimated normals"
    with pytest.raises(ValueError, match=f"{want}; the given normals keep their signs"):
        pssd_fast.denoise(points, normals, orient="up")
    if tile_points:
        with pytest.raises(ValueError, match=f"{want}; the normals of .*with.las keep"):
            pssd_fast.tiled.denoise_file(source, tmp_path / "t.las", tile_points=tile_points,
                                         orient="up", client="sync")
    flags = ("--tile-points", str(tile_points)) if tile_points else ()
    status, _, err = pssd("denoise", source, tmp_path / "out.las", "--orient", "up", *flags)
    assert_one_line_error(status, err, f"--{want}; the normals of {source} keep their signs "
                                       "(drop --orient)")
    assert not (tmp_path / "out.las").exists() and not (tmp_path / "t.las").exists()


def test_the_bar_fills_by_iterations_and_numbers_a_stage_run_again():
    """The passes over a file come before the first iteration; a tile's round moves the bar by
    nothing; the refinement's second iteration runs within the method's last, and its stages
    say so; the bar is full only when the run ends."""
    progress = cli._Progress(7, False)
    steps = [(0, 0, "read 1/2"), (0, 0, "buckets"), (1, 2, "tile_lists 1/3"), (1, 2, "neighbors"),
             (2, 2, "neighbors"), (2, 2, "refine_fit"), *[(2, 2, "refine_fit")] * 12]
    lines = [progress.line(*step) for step in steps]
    assert [line.split("] ")[1].rstrip() for line in lines[:7]] == [
        "preparing read 1/2", "preparing buckets", "iteration 1/2 tile_lists 1/3",
        "iteration 1/2 neighbors", "iteration 2/2 neighbors", "iteration 2/2 refine_fit",
        "iteration 2/2 refine_fit #2"]
    filled = [line.split("]")[0].count("#") for line in lines]
    assert filled[:3] == [0, 0, 0] and filled == sorted(filled)
    assert filled[3] == 2 and filled[4] == 17 and filled[-1] == 27  # (1 + 6/7) / 2 of 30


def test_the_bar_fits_the_terminal_and_is_wiped_whole(monkeypatch):
    """A line longer than the terminal would wrap and leave stale rows: each is cut one column
    short of the width and padded to it, and closing blanks that width."""
    import io as stdio
    import shutil

    class Terminal(stdio.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(shutil, "get_terminal_size", lambda: os.terminal_size((70, 24)))
    progress = cli._Progress(7, True)
    progress(2, 2, "refine_neighbors", 1.0)
    progress(2, 2, "refine_neighbors", 1.0)
    progress.close()
    written = terminal.getvalue().split("\r")[1:]
    assert [len(part) for part in written] == [69, 69, 69, 0]
    assert written[1].startswith("[") and "refine_neighbors #2 el" in written[1]
    assert not written[1].endswith(" ") and written[2] == " " * 69
