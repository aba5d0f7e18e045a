"""The clouds of other libraries in and out (``pssd_fast.interop``): the real Open3D and trimesh
where they are installed, structured arrays always."""
import ast
import sys

import numpy as np
import pytest

import pssd_fast
from pssd_fast import datasets, interop

#: The runs here check the plumbing, not the accuracy: the cheapest preset.
FAST = {"preset": "fast"}


@pytest.fixture(scope="module")
def part():
    """A small noisy CAD part, (n, 3) float64, writable."""
    return np.array(datasets.make("cad_part", n_points=2500, noise=0.004, seed=3).points)


@pytest.fixture(scope="module")
def expected(part):
    return pssd_fast.denoise(part, **FAST)


def records(points, names=("X", "Y", "Z"), kind="f8", extra=()):
    """A structured array of ``points`` in fields ``names`` of type ``kind``, plus ``extra``
    fields (name, dtype) filled with their row numbers."""
    out = np.zeros(points.shape[0], [(name, kind) for name in names] + list(extra))
    for axis, name in enumerate(names):
        out[name] = points[:, axis]
    for name, _ in extra:
        out[name] = np.arange(points.shape[0]) % 200
    return out


def same(a, b):
    """Bit for bit (NaN where NaN)."""
    return a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)


# Structured arrays: no optional library needed.

@pytest.mark.parametrize("names", [("X", "Y", "Z"), ("x", "y", "z")])
def test_a_structured_array_is_denoised_as_its_coordinates(part, expected, names):
    cloud = records(part, names, extra=[("Intensity", "u2"), ("Classification", "u1")])
    result = pssd_fast.denoise(cloud, **FAST)
    assert same(result.points, expected.points) and same(result.normals, expected.normals)
    back = interop.to_structured(result, like=cloud)
    assert back.dtype == cloud.dtype and back is not cloud
    np.testing.assert_array_equal(np.column_stack([back[n] for n in names]), expected.points)
    for name in ("Intensity", "Classification"):
        np.testing.assert_array_equal(back[name], cloud[name])
    np.testing.assert_array_equal(cloud[names[0]], part[:, 0])  # the input is untouched


def test_a_cloud_read_from_a_file_is_denoised_as_its_coordinates(part, expected, tmp_path):
    from pssd_fast import io
    path = io.write(tmp_path / "scan.npy", part)
    cloud = io.read(path)
    result = pssd_fast.denoise(cloud, **FAST)
    assert same(result.points, expected.points) and same(result.normals, expected.normals)
    points, normals = interop.as_arrays(io.PointCloud(part, -part))
    assert same(points, part) and same(normals, -part)


def test_float32_fields_give_a_float32_result(part):
    cloud = records(part, kind="f4")
    result = pssd_fast.denoise(cloud, **FAST)
    assert same(result.points, pssd_fast.denoise(part.astype(np.float32), **FAST).points)
    assert interop.to_structured(result, like=cloud).dtype == cloud.dtype


def test_normals_go_back_into_normal_fields(part, expected):
    cloud = records(part, extra=[("Intensity", "u2")])
    plain = interop.to_structured(expected, like=cloud)
    assert plain.dtype == cloud.dtype  # no field added unless asked
    added = interop.to_structured(expected, like=cloud, add_normals=True)
    assert added.dtype.names == cloud.dtype.names + ("NormalX", "NormalY", "NormalZ")
    np.testing.assert_array_equal(
        np.column_stack([added[n] for n in ("NormalX", "NormalY", "NormalZ")]),
        expected.normals)
    points, normals = interop.as_arrays(added)
    np.testing.assert_array_equal(points, expected.points)
    np.testing.assert_array_equal(normals, expected.normals)
    lower = interop.to_structured(expected, like=records(part, ("x", "y", "z")),
                                  add_normals=True)
    assert lower.dtype.names[-3:] == ("nx", "ny", "nz")


def test_rows_of_other_classes_keep_their_normal_fields(part):
    normal = [("NormalX", "f8"), ("NormalY", "f8"), ("NormalZ", "f8")]
    given = records(part, extra=[("Classification", "u1")] + normal)
    given["Classification"] = np.where(np.arange(part.shape[0]) < 1500, 2, 5)
    for name, column in zip(("NormalX", "NormalY", "NormalZ"),
                            pssd_fast.estimate_normals(part, k=16).T):
        given[name] = column
    result = pssd_fast.denoise(given, classification=given["Classification"], classes=[2],
                               **FAST)
    assert np.isnan(result.normals[1500:]).all()
    back = interop.to_structured(result, like=given)
    assert back.dtype == given.dtype
    for name in ("X", "Y", "Z", "NormalX", "NormalY", "NormalZ"):
        np.testing.assert_array_equal(back[name][1500:], given[name][1500:])
        assert not np.array_equal(back[name][:1500], given[name][:1500])
    np.testing.assert_array_equal(back["NormalZ"][:1500], result.normals[:1500, 2])


def test_outliers_removed_keep_the_rows_of_the_input(part):
    rng = np.random.default_rng(0)
    noisy = np.concatenate([part, rng.uniform(-1, 2, (40, 3))])
    cloud = records(noisy, extra=[("Intensity", "u2")])
    result = pssd_fast.denoise(cloud, remove_outliers=True, **FAST)
    assert result.kept.shape[0] < noisy.shape[0]
    back = interop.to_structured(result, like=cloud)
    np.testing.assert_array_equal(back["Intensity"], cloud["Intensity"][result.kept])
    np.testing.assert_array_equal(back["X"], result.points[:, 0])
    with pytest.raises(ValueError, match="like has 2000 points and the result"):
        interop.to_structured(result, like=cloud[:2000])
    # A larger cloud than the one denoised is refused too, not paired with its first rows.
    with pytest.raises(ValueError, match=f"like has {noisy.shape[0] + 7} points"):
        interop.to_structured(result, like=np.concatenate([cloud, cloud[:7]]))


def test_a_like_larger_than_the_cloud_denoised_is_refused(part, expected):
    cloud = records(part, extra=[("Intensity", "u2")])
    with pytest.raises(ValueError, match=f"like has {part.shape[0] + 7} points and the result "
                                         f"{part.shape[0]}; pass the cloud that was denoised"):
        interop.to_structured(expected, like=np.concatenate([cloud[::-1], cloud[:7]]))


def test_the_stage_functions_take_a_structured_array(part):
    cloud = records(part)
    assert same(pssd_fast.estimate_normals(cloud, k=16), pssd_fast.estimate_normals(part, k=16))
    assert same(pssd_fast.outlier_score(cloud), pssd_fast.outlier_score(part))
    graph = pssd_fast.neighbors(cloud, k=12)
    np.testing.assert_array_equal(graph.indices, pssd_fast.neighbors(part, k=12).indices)


def test_tiled_runs_take_a_structured_array(part):
    pytest.importorskip("dask")
    from pssd_fast import tiled

    cloud = records(part)
    got = tiled.denoise(cloud, client="sync", **FAST)
    assert same(got.points, tiled.denoise(part, client="sync", **FAST).points)


@pytest.mark.parametrize("cloud, error, match", [
    (np.zeros(5, [("X", "i4"), ("Y", "i4"), ("Z", "i4")]), TypeError,
     r"X, Y, Z must be floating point; got int32.*pass las\.xyz"),
    (np.zeros(5, [("east", "f8"), ("north", "f8"), ("up", "f8")]), TypeError,
     "needs fields X, Y, Z or x, y, z; got east, north, up"),
    (np.zeros((5, 2), [("X", "f8"), ("Y", "f8"), ("Z", "f8")]), ValueError,
     r"must be 1-D; got shape \(5, 2\)"),
])
def test_a_structured_array_without_coordinates_is_refused(cloud, error, match):
    with pytest.raises(error, match=match):
        pssd_fast.denoise(cloud)


class _LasLike:
    """What matters of laspy's ``LasData`` here: ``points`` (records) and ``xyz``."""
    points = np.zeros(3, [("X", "i4")])
    xyz = np.zeros((3, 3))


class _MeshLike:
    vertices = np.zeros((3, 3))


@pytest.mark.parametrize("thing, match", [
    (object(), r"got object; pass an \(n, 3\) array of coordinates \(Open3D and trimesh point "
               r"clouds and structured arrays .*pssd_fast\.interop\)"),
    (_LasLike(), r"got tests\.test_interop\._LasLike; .*: obj\.xyz$"),
    (_MeshLike(), r"got tests\.test_interop\._MeshLike; .*: np\.asarray\(obj\.vertices\)$"),
])
def test_another_object_gets_a_message_that_names_its_conversion(thing, match):
    with pytest.raises(TypeError, match=match):
        pssd_fast.denoise(thing)
    with pytest.raises(TypeError, match=match):
        pssd_fast.estimate_normals(thing)
    with pytest.raises(TypeError, match="cannot take the points of"):
        interop.as_arrays(thing)


def test_an_array_of_objects_keeps_its_dtype_hint():
    with pytest.raises(TypeError, match=r"dtype object .*\.astype\(np\.float64\)"):
        pssd_fast.denoise(np.zeros((20, 3), dtype=object))
    with pytest.raises(TypeError, match=r"^normals must be an \(n, 3\) array of real numbers; "
                                        r"got object$"):
        pssd_fast.denoise(np.zeros((20, 3)), normals=object())


def test_the_module_imports_open3d_and_trimesh_only_inside_its_functions():
    tree = ast.parse(open(interop.__file__, encoding="utf-8").read())
    top = {alias.name.split(".")[0] for node in tree.body if isinstance(node, ast.Import)
           for alias in node.names}
    top |= {node.module.split(".")[0] for node in tree.body
            if isinstance(node, ast.ImportFrom) and node.module}
    assert top == {"importlib", "numpy", "sys"}


@pytest.mark.parametrize("convert, name", [(interop.to_open3d, "open3d"),
                                           (interop.to_trimesh, "trimesh")])
def test_a_missing_library_is_named_with_how_to_install_it(part, monkeypatch, convert, name):
    monkeypatch.setitem(sys.modules, name, None)  # as if not installed: its import fails
    with pytest.raises(ImportError, match=f"needs {name}, which is not installed: pip install "
                                          f"{name} "):
        convert(part)


def test_results_as_plain_arrays_and_bad_results_are_named(part):
    back = interop.to_structured(part + 1.0, like=records(part))
    np.testing.assert_array_equal(back["Z"], part[:, 2] + 1.0)
    with pytest.raises(TypeError, match="result must be a DenoiseResult or an"):
        interop.to_structured(part[:, :2], like=records(part))
    with pytest.raises(TypeError, match="like must be a 1-D structured array"):
        interop.to_structured(part, like=part)


# Open3D

@pytest.fixture(scope="module")
def o3d():
    return pytest.importorskip("open3d")


def test_denoise_takes_a_legacy_open3d_cloud(o3d, part, expected):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(part))
    pcd.paint_uniform_color([0.25, 0.5, 0.75])
    result = pssd_fast.denoise(pcd, **FAST)
    assert same(result.points, expected.points) and same(result.normals, expected.normals)
    clean = interop.to_open3d(result)
    assert isinstance(clean, o3d.geometry.PointCloud) and not clean.has_colors()
    np.testing.assert_array_equal(np.asarray(clean.points), expected.points)
    np.testing.assert_array_equal(np.asarray(clean.normals), expected.normals)
    kept = interop.to_open3d(result, like=pcd)
    np.testing.assert_array_equal(np.asarray(kept.colors), np.asarray(pcd.colors))
    np.testing.assert_array_equal(np.asarray(kept.points), expected.points)
    np.testing.assert_array_equal(np.asarray(pcd.points), part)  # the input is untouched


def test_an_open3d_clouds_own_normals_are_not_used_unless_passed(o3d, part, expected):
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(part))
    pcd.estimate_normals()
    assert same(pssd_fast.denoise(pcd, **FAST).points, expected.points)
    points, normals = interop.as_arrays(pcd)
    np.testing.assert_array_equal(normals, np.asarray(pcd.normals))
    given = pssd_fast.denoise(points, normals, **FAST)
    assert not np.array_equal(given.points, expected.points)
    normals[:] = 0  # a copy: the cloud keeps its normals
    assert np.abs(np.asarray(pcd.normals)).sum() > 0


def test_denoise_takes_a_tensor_open3d_cloud(o3d, part):
    single = part.astype(np.float32)
    tpcd = o3d.t.geometry.PointCloud(o3d.core.Tensor(single))
    tpcd.point.colors = o3d.core.Tensor(np.full_like(single, 0.5))
    result = pssd_fast.denoise(tpcd, **FAST)
    reference = pssd_fast.denoise(single, **FAST)
    assert same(result.points, reference.points) and result.points.dtype == np.float32
    clean = interop.to_open3d(result, tensor=True, like=tpcd)
    assert isinstance(clean, o3d.t.geometry.PointCloud)
    np.testing.assert_array_equal(clean.point.positions.numpy(), reference.points)
    np.testing.assert_array_equal(clean.point.normals.numpy(), reference.normals)
    np.testing.assert_array_equal(clean.point.colors.numpy(), np.full_like(single, 0.5))
    bare = interop.to_open3d(reference, tensor=True)
    assert "colors" not in bare.point and bare.point.positions.dtype == o3d.core.float32
    points, normals = interop.as_arrays(clean)
    assert same(points, reference.points) and same(normals, reference.normals)


def test_open3d_results_after_removing_outliers(o3d, part):
    rng = np.random.default_rng(1)
    noisy = np.concatenate([part, rng.uniform(-1, 2, (40, 3))])
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(noisy))
    pcd.colors = o3d.utility.Vector3dVector(rng.uniform(0, 1, noisy.shape))
    result = pssd_fast.denoise(pcd, remove_outliers=True, **FAST)
    clean = interop.to_open3d(result, like=pcd)
    assert len(clean.points) == result.kept.shape[0] < noisy.shape[0]
    np.testing.assert_array_equal(np.asarray(clean.colors), np.asarray(pcd.colors)[result.kept])
    wrong = r"like must be an open3d\.geometry\.PointCloud with tensor=False; got .*\.t\."
    with pytest.raises(TypeError, match=wrong):
        interop.to_open3d(result, like=o3d.t.geometry.PointCloud.from_legacy(pcd))
    tensor = o3d.t.geometry.PointCloud.from_legacy(pcd)
    back = interop.to_open3d(result, tensor=True, like=tensor)
    np.testing.assert_array_equal(back.point.colors.numpy(),
                                  tensor.point.colors.numpy()[result.kept])


def test_an_open3d_mesh_is_refused_with_its_conversion(o3d):
    mesh = o3d.geometry.TriangleMesh.create_box()
    with pytest.raises(TypeError, match=r"TriangleMesh; .*np\.asarray\(obj\.vertices\)"):
        pssd_fast.denoise(mesh)


# trimesh

def test_denoise_takes_a_trimesh_cloud(part, expected):
    trimesh = pytest.importorskip("trimesh")
    colors = np.tile(np.array([200, 120, 40, 255], np.uint8), (part.shape[0], 1))
    cloud = trimesh.PointCloud(part, colors=colors)
    result = pssd_fast.denoise(cloud, **FAST)
    assert same(result.points, expected.points)
    clean = interop.to_trimesh(result, like=cloud)
    assert isinstance(clean, trimesh.PointCloud)
    np.testing.assert_array_equal(clean.vertices, expected.points)
    np.testing.assert_array_equal(clean.metadata["vertex_normals"], expected.normals)
    np.testing.assert_array_equal(clean.colors, colors)
    points, normals = interop.as_arrays(clean)
    np.testing.assert_array_equal(normals, expected.normals)
    assert "vertex_normals" not in interop.to_trimesh(part).metadata
    with pytest.raises(TypeError, match=r"Trimesh; .*np\.asarray\(obj\.vertices\)"):
        pssd_fast.denoise(trimesh.creation.box())
