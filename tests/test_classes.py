"""Denoising only some LAS classes: ``classes=`` and ``pssd denoise --classes``."""
import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets

from .conftest import pssd
from .test_support import DEFAULT_LIDAR_DIR


@pytest.fixture(scope="module")
def labelled():
    """The CAD part with a ground class (2) and a second class (1) of stray points."""
    points = np.array(datasets.make("cad_part", n_points=4000, noise=0.004, seed=5).points)
    rng = np.random.default_rng(5)
    labels = np.where(rng.random(len(points)) < 0.3, 1, 2).astype(np.uint8)
    return points, labels


def test_only_the_named_classes_move(labelled):
    points, labels = labelled
    result = pssd_fast.denoise(points, classification=labels, classes=[2])
    ground = labels == 2
    alone = pssd_fast.denoise(points[ground])
    # The other points are nobody's neighbours: the ground's result is that of the ground alone.
    for name in ("points", "normals", "likelihood", "feature_intensity", "displacement",
                 "held"):
        np.testing.assert_array_equal(getattr(result, name)[ground], getattr(alone, name),
                                      err_msg=name)
    np.testing.assert_array_equal(result.points[~ground], points[~ground])
    assert np.isnan(result.normals[~ground]).all() and np.isnan(result.likelihood[~ground]).all()
    assert (result.displacement[~ground] == 0).all() and not result.held[~ground].any()
    assert result.outlier_score is None and alone.outlier_score is None  # none asked for
    assert result.stats["classes"] == {"classes": [2], "denoised": int(ground.sum()),
                                       "untouched": int((~ground).sum())}
    np.testing.assert_array_equal(result.kept, np.arange(len(points)))


def test_classes_keep_given_normals_and_work_with_outlier_removal(labelled):
    points, labels = labelled
    # At k: the walks of select_scales change nothing here and cost most of the runs.
    at_k = {"select_scales": False}
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    result = pssd_fast.denoise(points, normals, classification=labels, classes=(1, 2, 9), **at_k)
    whole = pssd_fast.denoise(points, normals, **at_k)
    np.testing.assert_array_equal(result.points, whole.points)  # every point chosen
    one = labels == 1
    result = pssd_fast.denoise(points, normals, classification=labels, classes=2, **at_k)
    np.testing.assert_array_equal(result.normals[one], normals[one])
    removed = pssd_fast.denoise(points, classification=labels, classes=[2],
                                remove_outliers=True, **at_k)
    ground = np.flatnonzero(labels == 2)
    alone = pssd_fast.denoise(points[ground], remove_outliers=True, **at_k)
    np.testing.assert_array_equal(removed.kept,
                                  np.sort(np.concatenate([np.flatnonzero(one),
                                                          ground[alone.kept]])))
    # The scores are the ground's own, NaN on the points of the other classes.
    at = np.isin(removed.kept, ground)
    assert np.isnan(removed.outlier_score[~at]).all()
    np.testing.assert_array_equal(removed.outlier_score[at], alone.outlier_score)


def test_normals_outside_the_classes_are_kept_as_given(labelled):
    """The points outside the classes keep their normals as given, NaN included (as a classes
    run returns them); only the chosen points' normals are checked."""
    points, labels = labelled
    one = labels == 1
    normals = np.tile([0.0, 0.0, 2.0], (len(points), 1))
    normals[one] = np.nan
    normals[np.flatnonzero(one)[0]] = [3.0, 0.0, 0.0]
    result = pssd_fast.denoise(points, normals, classification=labels, classes=[2],
                               iterations=1, select_scales=False)
    np.testing.assert_array_equal(result.normals[one], normals[one])
    assert np.isfinite(result.normals[~one]).all()
    normals[np.flatnonzero(~one)[0]] = np.nan
    with pytest.raises(ValueError, match=r"normals \(of the chosen classes\) contains NaN or "
                                         r"Inf in 1 row"):
        pssd_fast.denoise(points, normals, classification=labels, classes=[2])


@pytest.mark.parametrize("ext", [".las", ".ply", ".xyz"])
def test_a_classes_output_denoises_and_renders_again(tmp_path, labelled, ext):
    """What ``--classes`` writes (NaN normals outside the classes) reads back: denoised again
    whole (every normal estimated, after a note), with the same classes, with the other class
    (whose points keep the file's normals) and drawn."""
    if ext != ".xyz":
        pytest.importorskip({".las": "laspy", ".ply": "plyfile"}[ext])
    from pssd_fast import io

    points, labels = labelled
    source = tmp_path / f"in{ext}"
    io.write(source, io.PointCloud(points, None, {"classification": labels}))
    fast = ("--preset", "fast", "--iterations", "1", "--quiet")
    first = tmp_path / f"first{ext}"
    status, _, err = pssd("denoise", source, first, "--classes", "2", *fast)
    assert status == 0, err
    written = io.read(first)
    one = written.fields["classification"] == 1
    assert np.isnan(written.normals[one]).all() and np.isfinite(written.normals[~one]).all()
    note = "have no normal (NaN or zeros); every normal is estimated, none read from the file"
    for name, extra, warned in (("whole", (), True), ("again", ("--classes", "2"), False),
                                ("other", ("--classes", "1"), True)):
        out = tmp_path / f"{name}{ext}"
        status, _, err = pssd("denoise", first, out, *extra, *fast)
        assert status == 0, err
        assert (note in err) == warned, err
        normals = io.read(out).normals
        if name == "again":
            assert np.isnan(normals[one]).all() and np.isfinite(normals[~one]).all()
        else:
            assert np.isfinite(normals).all()
        if name == "other":  # the ground keeps the normals of the first run
            np.testing.assert_array_equal(normals[~one], written.normals[~one])
    if ext == ".las":
        pytest.importorskip("matplotlib")
        status, _, err = pssd("render", first, "-o", tmp_path / "first.png", "--size", "200",
                              "150", "--quiet")
        assert status == 0 and note in err, err
        assert (tmp_path / "first.png").stat().st_size > 0


@pytest.mark.parametrize("kwargs, error, match", [
    ({"classes": [2]}, ValueError, "classes and classification go together"),
    ({"classification": np.zeros(4000, np.uint8)}, ValueError, "go together"),
    ({"classification": np.zeros(10, np.uint8), "classes": [2]}, ValueError, r"shape \(4000,\)"),
    ({"classification": np.zeros(4000), "classes": [2]}, TypeError, "integers"),
    ({"classification": np.zeros(4000, np.uint8), "classes": ["2"]}, TypeError, "integers"),
    ({"classification": np.zeros(4000, np.uint8), "classes": []}, ValueError, "empty"),
    ({"classification": np.zeros(4000, np.uint8), "classes": [2]}, ValueError,
     "no point is of class 2; the classes present are 0"),
])
def test_bad_classes_are_named(labelled, kwargs, error, match):
    with pytest.raises(error, match=match):
        pssd_fast.denoise(labelled[0], **kwargs)


@pytest.mark.slow
def test_pssd_denoise_classes_leaves_other_records_byte_for_byte(tmp_path):
    """The issue's check, on the shared airborne survey: ``--classes 2`` leaves every class-1
    record as it was, byte for byte (the records' own bytes; the added fields follow them)."""
    laspy = pytest.importorskip("laspy")
    source = DEFAULT_LIDAR_DIR / "autzen_trim.laz"
    if not source.is_file():
        pytest.skip(f"LiDAR file {source} not found")
    out = tmp_path / "out.laz"
    status, _, err = pssd("denoise", source, out, "--classes", "2", "--fields",
                          "displacement,held", "--quiet")
    assert status == 0, err
    before, after = laspy.read(str(source)), laspy.read(str(out))
    size = before.points.array.dtype.itemsize
    old = before.points.array.view(np.uint8).reshape(len(before.points), size)
    new = after.points.array.view(np.uint8).reshape(len(after.points), -1)[:, :size]
    other = np.asarray(before.classification) != 2
    assert other.sum() > 10_000
    np.testing.assert_array_equal(new[other], old[other])
    assert (np.asarray(after["displacement"])[other] == 0).all()
    ground = ~other
    assert (new[ground] != old[ground]).any(axis=1).mean() > 0.5  # the ground moved
    assert set(np.unique(after["held"])) <= {0, 1}


def test_pssd_denoise_classes_needs_a_classification(tmp_path):
    points = np.array(datasets.make("cad_part", n_points=500, noise=0.004, seed=5).points)
    np.savetxt(tmp_path / "in.xyz", points)
    status, _, err = pssd("denoise", tmp_path / "in.xyz", tmp_path / "out.xyz", "--classes",
                          "2")
    assert status == 1 and "Traceback" not in err and "has no classification field" in err
    status, _, err = pssd("denoise", tmp_path / "in.xyz", tmp_path / "out.xyz", "--classes",
                          "ground")
    assert status == 2 and "comma-separated class numbers" in err
