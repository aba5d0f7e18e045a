"""The PDAL ``filters.python`` stage, called as PDAL's plugin calls it (tests/pdal_like.py): no
PDAL needed."""
import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pssd_fast
from pssd_fast import pdal_filter

from . import pdal_like
from .conftest import PACKAGE_PARENT, data_file

#: The stage with the cheapest preset: these tests check the contract, not the accuracy.
FAST = {"preset": "fast"}


@pytest.fixture(scope="module")
def view():
    return pdal_like.survey()


def xyz(dims, rows=slice(None)):
    return np.column_stack([dims[axis][rows] for axis in "XYZ"])


def test_the_function_takes_ins_and_outs_only():
    assert inspect.getfullargspec(pdal_filter.denoise).args == ["ins", "outs"]
    stage = pdal_filter.stage()
    assert stage["script"] == str(Path(pdal_filter.__file__).resolve())
    assert (stage["type"], stage["function"]) == ("filters.python", "denoise")
    assert json.loads(stage["pdalargs"]) == {}


def test_each_surface_class_is_denoised_as_a_cloud_of_its_own(view):
    out = pdal_like.run_stage(pdal_filter.stage(**FAST), view)
    labels = view["Classification"]
    for code in (2, 6):
        rows = labels == code
        alone = pssd_fast.denoise(xyz(view, rows), **FAST).points
        np.testing.assert_array_equal(xyz(out, rows), alone)
    others = ~np.isin(labels, (2, 6))
    assert others.sum() == 550
    for name, values in view.items():  # every other dimension, and the other classes' X, Y, Z
        rows = others if name in "XYZ" else slice(None)
        assert out[name].dtype == values.dtype
        np.testing.assert_array_equal(out[name][rows], values[rows], err_msg=name)


def test_only_x_y_z_come_back_as_float64(view):
    stage = pdal_filter.stage(**FAST)
    ins = {name: values.copy() for name, values in view.items()}
    outs = {}
    pdal_filter.pdalargs = json.loads(stage["pdalargs"])
    try:
        assert pdal_filter.denoise(ins, outs) is True
    finally:
        pdal_filter.pdalargs = None
    assert sorted(outs) == ["X", "Y", "Z"]
    for values in outs.values():
        assert values.dtype == np.float64 and values.shape == view["X"].shape
        assert values.flags.c_contiguous
    for name, values in view.items():  # ins is left as it came
        np.testing.assert_array_equal(ins[name], values)


def test_classes_named_in_pdalargs(view):
    out = pdal_like.run_stage(pdal_filter.stage(classes=[6], **FAST), view)
    roof = view["Classification"] == 6
    np.testing.assert_array_equal(xyz(out, ~roof), xyz(view, ~roof))
    assert not np.array_equal(xyz(out, roof), xyz(view, roof))
    everything = pdal_like.run_stage(pdal_filter.stage(classes="all", **FAST), view)
    np.testing.assert_array_equal(xyz(everything), pssd_fast.denoise(xyz(view), **FAST).points)


def test_the_defaults_without_pdalargs(view, monkeypatch):
    """PDAL's ``pdalargs`` unset: the global is None (PDAL 2.4 and later; older versions leave
    it out, and the module's own None stands). A value set on the imported module does not
    reach the module PDAL loads (docs/interop.md)."""
    monkeypatch.setattr(pdal_filter, "pdalargs", {"classes": "all"})
    stage = {key: value for key, value in pdal_filter.stage().items() if key != "pdalargs"}
    small = {name: values[::16] for name, values in view.items()}
    out = pdal_like.run_stage(stage, small)
    for code in (2, 6):
        rows = small["Classification"] == code
        np.testing.assert_array_equal(xyz(out, rows),
                                      pssd_fast.denoise(xyz(small, rows)).points)


def test_a_view_without_classification_is_one_cloud(view):
    bare = {name: view[name] for name in ("X", "Y", "Z", "Intensity")}
    out = pdal_like.run_stage(pdal_filter.stage(**FAST), bare)
    np.testing.assert_array_equal(xyz(out), pssd_fast.denoise(xyz(view), **FAST).points)
    with pytest.raises(ValueError, match="classes needs a Classification dimension"):
        pdal_like.run_stage(pdal_filter.stage(classes=[2]), bare)


@pytest.mark.parametrize("codes", [[0], [0, 1]])
def test_a_view_of_unclassified_points_is_one_cloud(view, codes):
    """Classes 0 and 1 alone are no classification, as pssd_fast.denoise takes them."""
    unclassified = dict(view, Classification=np.resize(np.array(codes, np.uint8),
                                                        view["X"].shape[0]))
    out = pdal_like.run_stage(pdal_filter.stage(**FAST), unclassified)
    np.testing.assert_array_equal(xyz(out), pssd_fast.denoise(
        xyz(view), classification=unclassified["Classification"], **FAST).points)
    assert not np.array_equal(xyz(out), xyz(view))


def test_nothing_changes_without_a_surface_class(view, capsys):
    trees = {name: values[view["Classification"] == 5] for name, values in view.items()}
    outs = {}
    assert pdal_filter.denoise(trees, outs) is True and outs == {}
    few = {name: values[:2008] for name, values in view.items()}
    few["Classification"][2000:] = 6  # 8 points of class 6: too few, left as they are
    out = pdal_like.run_stage(pdal_filter.stage(**FAST), few)
    np.testing.assert_array_equal(xyz(out, slice(2000, None)), xyz(few, slice(2000, None)))
    assert "class 6: 8 points, fewer than 11; left as they are" in capsys.readouterr().out
    # Enough points of a class at too few positions: left as they are too, as denoise does.
    few["X"][2000:], few["Y"][2000:], few["Z"][2000:] = few["X"][2000], few["Y"][2000], 9.0
    few = {name: np.concatenate([values, values[2000:]]) for name, values in few.items()}
    out = pdal_like.run_stage(pdal_filter.stage(**FAST), few)
    np.testing.assert_array_equal(xyz(out, slice(2000, None)), xyz(few, slice(2000, None)))
    assert "class 6: 16 points at 1 distinct position, fewer than 11" in capsys.readouterr().out


@pytest.mark.parametrize("pdalargs, error, match", [
    ({"remove_outliers": True}, ValueError, "pdalargs remove_outliers: not in a PDAL stage"),
    ({"classes": "ground"}, ValueError, "list of class codes or 'all'; got 'ground'"),
    ({"classes": [2.5]}, TypeError, r"must be a list of class codes; got \[2.5\]"),
    ({"k": "many"}, TypeError, "k must be an integer"),
    ({"smoothness": 3}, TypeError, "unknown parameter"),
])
def test_bad_pdalargs_are_named(view, pdalargs, error, match):
    stage = {**pdal_filter.stage(), "pdalargs": json.dumps(pdalargs)}
    with pytest.raises(error, match=match):
        pdal_like.run_stage(stage, view)


def test_python_m_prints_the_script_path():
    env = {**os.environ, "PYTHONPATH": str(PACKAGE_PARENT)}
    done = subprocess.run([sys.executable, "-m", "pssd_fast.pdal_filter"], env=env,
                          capture_output=True, text=True, timeout=120, check=True)
    assert done.stdout.strip() == str(Path(pdal_filter.__file__).resolve())


def test_the_stand_in_refuses_what_pdal_refuses(view):
    """tests/pdal_like.py fails where PDAL's plugin does, so the tests above can pass only
    for a stage that keeps PDAL's contract."""
    cases = {"def f(ins, outs, more):\n    return True\n": "Only two arguments",
             "def f(ins, outs):\n    return 1\n": "not boolean",
             "def f(ins, outs):\n    outs['Height'] = ins['Z']\n    return True\n":
                 "Dimension not registered",
             "def f(ins, outs):\n    outs['X'] = ins['X'].astype('f4')\n    return True\n":
                 "byte size of 8",
             "def f(ins, outs):\n    outs['Intensity'] = ins['Intensity'].astype('i2')\n"
             "    return True\n": "dimension's type uint16"}
    for source, match in cases.items():
        with pytest.raises(RuntimeError, match=match):
            pdal_like.run_stage({"source": source, "module": "m", "function": "f"}, view)


@pytest.mark.slow
def test_the_stage_on_the_shared_survey():
    """The default stage on a part of the shared airborne survey (10,675 points, 2,538 of them
    ground; in feet): the unclassified returns keep their coordinates, and no ground point
    moves 1 m (3.28 feet; measured: 3.14 at most)."""
    pytest.importorskip("laspy")
    path = data_file("lidar", "autzen_trim.laz")
    dims = pdal_like.read_las(path)
    rel = xyz(dims)[:, :2] - xyz(dims)[:, :2].min(axis=0)
    inside = (rel[:, 0] >= 600) & (rel[:, 0] < 800) & (rel[:, 1] >= 150) & (rel[:, 1] < 330)
    part = {name: values[inside] for name, values in dims.items()}
    out = pdal_like.run_stage(pdal_filter.stage(), part)
    ground = part["Classification"] == 2
    np.testing.assert_array_equal(xyz(out, ~ground), xyz(part, ~ground))
    moved = np.linalg.norm(xyz(out, ground) - xyz(part, ground), axis=1)
    assert moved.max() < 1.0 / 0.3048 and np.median(moved) > 0
