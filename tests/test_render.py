"""Pictures: layout, z-buffer, views, shading, NaN colour, closed surfaces, atomic PNG writes."""
import os
import sys

import numpy as np
import pytest

from pssd_fast import datasets
from pssd_fast.pictures import render as rn

colormaps = pytest.importorskip("matplotlib").colormaps
imread = pytest.importorskip("matplotlib.image").imread

SIZE = (320, 240)
FRONT = (0.0, 0.0)  # looks along +y: x to the right, z up, smaller y nearer


def square(x0, z0, y, side=1.0, n=60):
    """A grid of n x n points filling a square in the plane y = const, facing the FRONT view."""
    u, v = np.meshgrid(np.linspace(0, side, n), np.linspace(0, side, n))
    return np.column_stack([x0 + u.ravel(), np.full(n * n, y), z0 + v.ravel()])


def drawn(image):
    """Mask of the pixels that are not the white background."""
    return (image[..., :3] < 255).any(axis=-1)


def left_part(image):
    """The picture without its colour bar (which starts at 83% of the width)."""
    return image[:, : int(0.8 * image.shape[1])]


def near_colour(image, rgb, tol=2):
    return (np.abs(image[..., :3].astype(int) - np.asarray(rgb)).max(axis=-1) <= tol)


def rgb255(cmap, x):
    return np.rint(np.asarray(colormaps[cmap](x)[:3]) * 255).astype(int)


def bbox(mask):
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return rows[0], rows[-1], cols[0], cols[-1]


# -- the picture and its file ------------------------------------------------------------------


@pytest.mark.parametrize("with_values", [False, True])
def test_shape_dtype_and_opaque(with_values):
    points = square(0, 0, 0)
    values = points[:, 0] if with_values else None
    image = rn.render(points, values, size=SIZE, title="t", label="x")
    assert image.shape == (240, 320, 4) and image.dtype == np.uint8
    assert (image[..., 3] == 255).all()
    assert drawn(image).mean() > 0.05


def test_png_written_readable_and_nothing_left_over(tmp_path):
    path = tmp_path / "pic.png"
    first = rn.render(square(0, 0, 0), path=path, size=SIZE)
    image = rn.render(square(0, 0, 0), square(0, 0, 0)[:, 2], path=str(path), size=(300, 200))
    read = imread(path)
    assert read.shape == (200, 300, 4)
    np.testing.assert_allclose(read, image / 255.0, atol=1e-6)
    assert first.shape == (240, 320, 4)
    assert os.listdir(tmp_path) == ["pic.png"]  # replaced in place, no temporary files


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    import matplotlib.image

    path = tmp_path / "pic.png"
    rn.render(square(0, 0, 0), path=path, size=SIZE)
    before = path.read_bytes()

    def broken(f, *args, **kwargs):
        f.write(b"half a png")
        raise OSError("disk full")

    monkeypatch.setattr(matplotlib.image, "imsave", broken)
    with pytest.raises(OSError, match="disk full"):
        rn.render(square(0, 0, 0), square(0, 0, 0)[:, 0], path=path, size=SIZE)
    assert os.listdir(tmp_path) == ["pic.png"]
    assert path.read_bytes() == before


def test_missing_matplotlib_names_the_extra(monkeypatch, tmp_path):
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(ImportError, match=r"pip install 'pssd_fast\[viz\]'"):
        rn.render(square(0, 0, 0))
    points = square(0, 0, 0)
    zeros = np.zeros(len(points))
    with pytest.raises(ImportError, match=r"pip install 'pssd_fast\[viz\]'"):
        rn.figure_set(tmp_path, points, points, likelihood=zeros, feature=zeros,
                      displacement=zeros)
    assert os.listdir(tmp_path) == []


# -- geometry of the picture -------------------------------------------------------------------


@pytest.mark.parametrize("far_first", [False, True])
def test_nearer_square_hides_the_farther_one(far_first):
    near = square(0.0, 0.0, y=-0.3)   # value 1
    far = square(0.5, 0.5, y=+0.3)    # value 0, overlapping the near one's upper right quarter
    parts = [(far, 0.0), (near, 1.0)] if far_first else [(near, 1.0), (far, 0.0)]
    points = np.vstack([p for p, _ in parts])
    values = np.concatenate([np.full(len(p), v) for p, v in parts])
    image = left_part(rn.render(points, values, view=FRONT, vmin=0, vmax=1, size=SIZE))
    near_px = near_colour(image, rgb255("viridis", 1.0))
    far_px = near_colour(image, rgb255("viridis", 0.0))
    # The union spans [0, 1.5] in x and z; the overlap [0.5, 1] sits in its middle third.
    top, bottom, left, right = bbox(drawn(image))
    assert near_px[(top + bottom) // 2, (left + right) // 2]
    # Near square fully visible (area 1), the far one less the overlap (area 0.75).
    # (the near square's discs must not spill over the far one).
    assert near_px.sum() / far_px.sum() == pytest.approx(1 / 0.75, rel=0.05)


def test_outline_does_not_grow_with_the_disc_size():
    widths = []
    for n in (50, 200):  # discs of about 8 and 2 pixels' radius
        top, bottom, left, right = bbox(drawn(rn.render(square(0, 0, 0, n=n), view=FRONT,
                                                        size=SIZE)))
        widths.append((right - left + 1, bottom - top + 1))
    assert np.abs(np.subtract(*widths)).max() <= 6


def test_view_rotates_about_z():
    rng = np.random.default_rng(0)
    rod = rng.uniform([-2, -0.25, -0.25], [2, 0.25, 0.25], (6000, 3))  # long along x
    width = {}
    for azimuth in (0.0, 90.0):
        top, bottom, left, right = bbox(drawn(rn.render(rod, view=(0.0, azimuth), size=SIZE)))
        width[azimuth] = (right - left + 1, bottom - top + 1)
    (w0, h0), (w90, h90) = width[0.0], width[90.0]
    assert w0 > 5 * h0 and w0 > 5 * w90
    assert h0 == pytest.approx(h90, abs=3) and w90 == pytest.approx(h90, abs=3)


def test_x_right_and_z_up_in_the_front_view_and_height():
    points = np.vstack([square(0.8, 0.8, 0, side=0.2), square(-1.0, -1.0, 0, side=0.2)])
    values = np.repeat([1.0, 0.0], len(points) // 2)  # the (+x, +z) corner is yellow
    image = left_part(rn.render(points, values, view=FRONT, vmin=0, vmax=1, size=SIZE))
    rows, cols = np.nonzero(near_colour(image, rgb255("viridis", 1.0)))
    other_rows, other_cols = np.nonzero(near_colour(image, rgb255("viridis", 0.0)))
    assert cols.mean() > other_cols.mean() and rows.mean() < other_rows.mean()
    np.testing.assert_array_equal(rn.height(points), points[:, 2])
    np.testing.assert_array_equal(rn.height(points, "y"), points[:, 1])


@pytest.mark.parametrize("up", ["x", "y", "z"])
@pytest.mark.parametrize("view", [FRONT, rn.DEFAULT_VIEW])
def test_the_up_axis_is_drawn_upwards(up, view):
    axis = "xyz".index(up)
    rng = np.random.default_rng(5)
    blobs = rng.normal(scale=0.1, size=(2, 2000, 3))
    blobs[0, :, axis] += 1.0  # the high blob, value 1
    blobs[1, :, axis] -= 1.0
    values = np.repeat([1.0, 0.0], 2000)
    image = left_part(rn.render(blobs.reshape(-1, 3), values, view=view, up=up, vmin=0, vmax=1,
                                size=SIZE))
    high_rows, _ = np.nonzero(near_colour(image, rgb255("viridis", 1.0), tol=60))
    low_rows, _ = np.nonzero(near_colour(image, rgb255("viridis", 0.0), tol=60))
    assert high_rows.size > 100 and low_rows.size > 100
    assert high_rows.max() < low_rows.min()  # the whole high blob above the low one


def test_a_y_up_model_faces_the_front_view():
    # y up: the model's front (+z) is nearer the camera than its back in the front view.
    front, back = square(0, 0, 0.3), square(0, 0, -0.3)
    for sq in (front, back):
        sq[:, [1, 2]] = sq[:, [2, 1]]  # squares in planes z = +-0.3, spanning x and y
    values = np.repeat([1.0, 0.0], len(front))
    image = left_part(rn.render(np.vstack([front, back]), values, view=FRONT, up="y", vmin=0,
                                vmax=1, size=SIZE))
    assert near_colour(image, rgb255("viridis", 1.0)).sum() > 0.95 * drawn(image).sum()


@pytest.mark.parametrize("extent, georeferenced, up", [
    ((0.7, 1.0, 1.0), False, "y"),     # Igea's box: no flat axis, the y-up convention
    ((0.44, 0.77, 1.0), False, "y"),   # the dragon's
    ((1.0, 0.43, 0.27), False, "z"),   # the generated CAD part: flat along z
    ((0.2, 1.0, 0.8), False, "x"),     # a facade
    ((1.0, 1.0, 0.05), False, "z"),    # a terrain
    ((1.0, 1.0, 0.05), True, "z"),
    ((0.05, 1.0, 1.0), True, "z"),     # LAS is z-up whatever its shape
])
def test_choose_up(extent, georeferenced, up):
    points = np.random.default_rng(6).uniform(size=(500, 3)) * extent
    assert rn.choose_up(points, georeferenced) == up


def test_headlight_shading_darkens_tilted_surfaces_and_ignores_orientation():
    points = square(0, 0, 0)
    n = len(points)
    tilt = np.radians(70.0)

    def grey(normals):
        image = rn.render(points, normals=normals, view=FRONT, size=SIZE)
        return image[drawn(image)][:, 0].mean()

    facing = grey(np.tile([0.0, -1.0, 0.0], (n, 1)))
    away = grey(np.tile([0.0, 1.0, 0.0], (n, 1)))           # same plane, normal flipped
    tilted = grey(np.tile([np.sin(tilt), -np.cos(tilt), 0.0], (n, 1)))
    unshaded = grey(None)
    light = rn.AMBIENT + (1 - rn.AMBIENT) * np.cos(tilt)
    assert facing == pytest.approx(255 * rn.PLAIN_GREY[0], abs=1)
    assert away == facing and unshaded == facing
    assert tilted == pytest.approx(light * facing, abs=2)


def test_nan_values_are_grey():
    points = square(0, 0, 0)
    values = np.where(points[:, 0] < 0.5, np.nan, 1.0)
    image = left_part(rn.render(points, values, view=FRONT, size=SIZE))
    rgb = image[drawn(image)][:, :3].astype(int)
    grey = (np.ptp(rgb, axis=1) == 0) & (np.abs(rgb[:, 0] - 255 * rn.NAN_GREY[0]) <= 1)
    assert 0.4 < grey.mean() < 0.6
    everything_nan = left_part(rn.render(points, np.full(len(points), np.nan), size=SIZE))
    assert (np.ptp(everything_nan[drawn(everything_nan)][:, :3], axis=1) == 0).all()


def test_sphere_is_closed_no_back_points_show_through():
    cloud = datasets.sphere(50_000, noise=0.0, seed=5)
    view = (20.0, 30.0)
    back = (cloud.points @ rn._basis(view)[2] < 0).astype(float)
    image = left_part(rn.render(cloud.points, back, view=view, normals=cloud.normals,
                                cmap="coolwarm", vmin=0, vmax=1, size=(600, 480)))
    mask = drawn(image)
    top, bottom, left, right = bbox(mask)
    radius = (bottom - top + right - left) / 4
    rows, cols = np.mgrid[: image.shape[0], : image.shape[1]]
    inner = np.hypot(rows - (top + bottom) / 2, cols - (left + right) / 2) < radius - 3
    assert mask[inner].all()
    # Back points are red (coolwarm's top end), front ones blue: red means see-through.
    rgb = image[inner][:, :3].astype(int)
    assert ((rgb[:, 0] - rgb[:, 2]) > 0).sum() == 0


# -- arguments and the figure set --------------------------------------------------------------


@pytest.mark.parametrize("kwargs, error, match", [
    ({"values": np.zeros(5)}, ValueError, r"shape \(3600,\)"),
    ({"view": 30.0}, TypeError, "elevation, azimuth"),
    ({"size": (10, 10)}, ValueError, "at least 64"),
    ({"vmin": 2.0, "vmax": 1.0}, ValueError, "vmin must not exceed vmax"),
    ({"normals": np.zeros((3600, 3))}, ValueError, "zero-length"),
])
def test_bad_arguments(kwargs, error, match):
    kwargs.setdefault("values", np.zeros(3600))
    with pytest.raises(error, match=match):
        rn.render(square(0, 0, 0), **kwargs)


def test_figure_set_writes_the_six_pictures_on_one_scale(tmp_path):
    cloud = datasets.sphere(4000, noise=0.01, seed=2)
    noisy, denoised = cloud.points, cloud.clean
    n = len(noisy)
    paths = rn.figure_set(tmp_path / "figs", noisy, denoised, likelihood=np.linspace(0, 1, n),
                          feature=np.zeros(n),
                          displacement=np.linalg.norm(noisy - denoised, axis=1),
                          normals_denoised=cloud.normals, size=SIZE)
    names = ["noisy.png", "curvature.png", "likelihood.png", "feature.png",
             "denoised_curvature.png", "denoised_displacement.png"]
    assert [p.name for p in paths] == names
    assert sorted(os.listdir(tmp_path / "figs")) == sorted(names)
    for path in paths:
        assert imread(path).shape == (240, 320, 4)
    # One fixed curvature scale: the noise of the input shows as strong reds and blues, the
    # clean sphere (H d = 3.5 everywhere, 7% of the scale) stays pale. Scaled per picture, the
    # clean sphere would be saturated too.
    for path, low, high in ((paths[1], 0.1, 1.0), (paths[4], 0.0, 0.01)):
        curv = left_part(np.rint(imread(path) * 255).astype(int))
        rgb = curv[drawn(curv)][:, :3]
        strong = np.abs(rgb[:, 0] - rgb[:, 2]) > 40
        assert low <= strong.mean() <= high, (path.name, strong.mean())
    noisy_png = imread(paths[0])[..., :3]
    assert np.ptp(noisy_png, axis=-1).max() < 1e-6  # grey


@pytest.mark.parametrize("field, value, position", [
    ("feature", 0.25, 0.25), ("likelihood", 0.6, 0.6), ("curvature", 25.0, 0.75),
    ("curvature", -100.0, 0.0), ("displacement", 0.005, 0.5)])
def test_each_field_has_one_fixed_scale(field, value, position):
    # A constant field would sit mid-scale if the limits came from the values.
    style = rn.STYLES[field]
    image = left_part(rn.render(square(0, 0, 0), np.full(3600, value), field=field, size=SIZE,
                                view=FRONT))
    assert near_colour(image, rgb255(style.cmap, position)).sum() > 0.95 * drawn(image).sum()


@pytest.mark.parametrize("name, magic", [("pic.png", b"\x89PNG"), ("pic.JPG", b"\xff\xd8\xff"),
                                         ("pic.jpeg", b"\xff\xd8\xff"), ("pic.tif", b"II*\x00")])
def test_the_format_follows_the_extension(tmp_path, name, magic):
    rn.render(square(0, 0, 0), square(0, 0, 0)[:, 0], path=tmp_path / name, size=SIZE)
    assert (tmp_path / name).read_bytes()[:len(magic)] == magic
    assert os.listdir(tmp_path) == [name]


@pytest.mark.parametrize("name, match", [("pic.bmp", "extension '.bmp'; supported: .png"),
                                         ("pic", "no extension")])
def test_an_unsupported_format_is_refused_before_drawing(tmp_path, name, match):
    with pytest.raises(ValueError, match=match):
        rn.render(square(0, 0, 0), path=tmp_path / name, size=SIZE)
    assert os.listdir(tmp_path) == []


def test_render_1k_points_any_order_same_picture():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(1000, 3))
    values = points[:, 2]
    perm = rng.permutation(1000)
    a = rn.render(points, values, size=SIZE, point_size=6)
    b = rn.render(points[perm], values[perm], size=SIZE, point_size=6)
    changed = (a != b).any(axis=-1).mean()
    assert changed < 0.002  # only exact ties at equal depth and distance may differ


@pytest.mark.parametrize("radius", [0.4, 1.0, 2.5, 4.0])
@pytest.mark.parametrize("reduce, identity", [(np.minimum, np.inf), (np.maximum, -np.inf)])
def test_disc_filter_matches_brute_force(radius, reduce, identity):
    rng = np.random.default_rng(4)
    image = rng.normal(size=(30, 40))
    padded = np.pad(image, 5, constant_values=identity)  # the disc is cut at the edges
    dy, dx = rn._disc(radius)
    shifted = [padded[5 + y:35 + y, 5 + x:45 + x] for y, x in zip(dy, dx, strict=True)]
    expected = reduce.reduce(shifted, axis=0)
    np.testing.assert_array_equal(rn._disc_filter(image, radius, reduce), expected)


def test_gap_in_a_surface_does_not_show_what_is_behind():
    # A 100 x 100 grid (spacing s = 0.01) with a hole of radius 5 s, in front of another sheet:
    # the hole is narrower than the closing (6 s here: the density estimate reads a grid's
    # spacing as 2 s) yet wider than the reach of one point (3 s).
    front = square(0.0, 0.0, y=-0.3, n=100)
    front = front[np.hypot(front[:, 0] - 0.5, front[:, 2] - 0.5) > 0.05]
    back = square(0.0, 0.0, y=+0.3, n=100)
    values = np.repeat([1.0, 0.0], [len(front), len(back)])
    image = left_part(rn.render(np.vstack([front, back]), values, view=FRONT, vmin=0, vmax=1,
                                size=(600, 480)))
    assert not near_colour(image, rgb255("viridis", 0.0)).any()
    assert near_colour(image, rgb255("viridis", 1.0)).sum() > 0.9 * drawn(image).sum()
