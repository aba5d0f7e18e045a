"""Pictures: layout, z-buffer, views, shading, NaN colour, closed surfaces, atomic PNG writes."""
import os
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pssd_fast import datasets
from pssd_fast.pictures import colours, splat, view
from pssd_fast.pictures import draw as rn

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
    # Each picture is fitted to its projection: the rod across, then end-on (a square).
    (w0, h0), (w90, h90) = width[0.0], width[90.0]
    assert w0 > 5 * h0
    assert w90 == pytest.approx(h90, abs=3)


def test_x_right_and_z_up_in_the_front_view_and_height():
    points = np.vstack([square(0.8, 0.8, 0, side=0.2), square(-1.0, -1.0, 0, side=0.2)])
    values = np.repeat([1.0, 0.0], len(points) // 2)  # the (+x, +z) corner is yellow
    image = left_part(rn.render(points, values, view=FRONT, vmin=0, vmax=1, size=SIZE))
    rows, cols = np.nonzero(near_colour(image, rgb255("viridis", 1.0)))
    other_rows, other_cols = np.nonzero(near_colour(image, rgb255("viridis", 0.0)))
    assert cols.mean() > other_cols.mean() and rows.mean() < other_rows.mean()
    np.testing.assert_array_equal(view.height(points), points[:, 2])
    np.testing.assert_array_equal(view.height(points, "y"), points[:, 1])


@pytest.mark.parametrize("up", ["x", "y", "z"])
@pytest.mark.parametrize("view", [FRONT, view.DEFAULT_VIEW])
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
    assert view.choose_up(points, georeferenced) == up


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
    seen_from = (20.0, 30.0)
    back = (cloud.points @ view.basis(seen_from)[2] < 0).astype(float)
    image = left_part(rn.render(cloud.points, back, view=seen_from, normals=cloud.normals,
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
    ({"size": (100_000, 100_000)}, ValueError, "width must be at most 8192"),
    ({"size": (1000, 9000)}, ValueError, "height must be at most 8192"),
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
    ("curvature", -100.0, 0.0)])
def test_each_field_has_one_fixed_scale(field, value, position):
    # A constant field would sit mid-scale if the limits came from the values.
    style = colours.STYLES[field]
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
    dy, dx = splat.disc(radius)
    shifted = [padded[5 + y:35 + y, 5 + x:45 + x] for y, x in zip(dy, dx, strict=True)]
    expected = reduce.reduce(shifted, axis=0)
    np.testing.assert_array_equal(splat.disc_filter(image, radius, reduce), expected)


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


# -- surveys: framing, views, colour modes -----------------------------------------------------


def strip(n=6000, length=400.0, width=100.0, turn=30.0, seed=7):
    """A survey-like strip: ``length`` x ``width`` with 10 units of relief, turned by ``turn``
    degrees about z (a wide, flat scene whose length runs along that direction)."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, length, n), rng.uniform(0, width, n)
    z = 5.0 * np.sin(u / 40.0) + 5.0 * (v / width)
    c, s = np.cos(np.radians(turn)), np.sin(np.radians(turn))
    return np.column_stack([c * u - s * v + 5e5, s * u + c * v + 4e6, z + 100.0])


def drawing_fill(image, margin):
    """Fractions of the drawing's width and height (the picture less ``margin`` pixels on
    each side, no title, no key) that the drawn pixels span."""
    top, bottom, left, right = bbox(drawn(image))
    h, w = image.shape[:2]
    return (right - left + 1) / (w - 2 * margin), (bottom - top + 1) / (h - 2 * margin)


@pytest.mark.parametrize("turn, azimuth", [(0.0, 0.0), (30.0, 30.0), (120.0, -60.0),
                                           (-75.0, -75.0), (90.0, 90.0)])
def test_a_flat_scene_is_seen_obliquely_with_its_length_across(turn, azimuth):
    elevation, found = view.choose_view(strip(turn=turn))
    assert elevation == view.SCENE_ELEVATION
    assert found == pytest.approx(azimuth, abs=1.0) or abs(found - azimuth) == pytest.approx(
        180.0, abs=1.0)
    assert -90.0 < found <= 90.0 or turn == 90.0


def test_a_slanted_survey_is_turned_to_its_smallest_rectangle_not_its_principal_axis():
    # A parallelogram with east-west long edges (like the Autzen strip): its principal axis is
    # 3 degrees off them, but its bounding rectangle is smallest north up.
    rng = np.random.default_rng(3)
    u, v = rng.uniform(0, 400, 6000), rng.uniform(0, 100, 6000)
    points = np.column_stack([u + 0.8 * v, v, np.zeros(6000)])
    assert view.choose_view(points) == (view.SCENE_ELEVATION, 0.0)


def test_a_cloud_that_is_not_flat_gets_the_default_view():
    assert view.choose_view(datasets.sphere(2000, noise=0.0, seed=1).points) == view.DEFAULT_VIEW
    # The up axis counts: a strip standing on its side is not flat about z, but is about x.
    upright = strip()[:, [2, 0, 1]]
    assert view.choose_view(upright) == view.DEFAULT_VIEW
    assert view.choose_view(upright, up="x")[0] == view.SCENE_ELEVATION


def test_a_wide_scene_fills_its_picture():
    points = strip(length=300.0)  # a picture 0.3 times as high as wide (FLATTEST) or more
    # Free height: the picture takes the strip's shape and the strip fills it both ways.
    image = rn.render(points, size=(400, None))
    assert image.shape[0] < 0.6 * image.shape[1]
    across, down = drawing_fill(image, margin=8)
    assert across > 0.9 and down > 0.85, (across, down)
    # A fixed, squarer size: the binding side is filled (the former frame, a sphere about the
    # cloud fitted to the short side, seen from (30, -60), spanned 31% of the width).
    across, _ = drawing_fill(rn.render(points, size=(400, 400)), margin=8)
    assert across > 0.9, across


def test_pictures_given_one_frame_line_up_with_or_without_a_key():
    points = strip(n=3000)
    values = points[:, 2]
    plain = rn.render(points, frame=points, title="t", size=(400, None))
    keyed = rn.render(points, values, frame=points, title="t", size=(400, None))
    assert plain.shape == keyed.shape
    assert bbox(drawn(plain)) == bbox(drawn(left_part(keyed)))


def square_cloud(n=40):
    """An n x n grid on the plane z = 0 (seen from straight above by TOP: no shading)."""
    u, v = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n))
    return np.column_stack([u.ravel(), v.ravel(), np.zeros(n * n)])


TOP = (90.0, 0.0)  # from straight above: x to the right, y up


def hex255(colour):
    from matplotlib.colors import to_rgb

    return np.rint(np.asarray(to_rgb(colour)) * 255).astype(int)


def test_classification_gets_asprs_colours_and_a_legend_naming_the_classes_present():
    points = square_cloud()
    codes = np.where(points[:, 0] < 0.5, 2, 6).astype(np.uint8)
    codes[points[:, 1] > 0.9] = 70
    fig = rn.figure(points, codes, field="classification", view=TOP, size=SIZE)
    legend, = fig.legends
    assert legend.get_title().get_text() == "classification"
    assert [t.get_text() for t in legend.get_texts()] == ["2 Ground", "6 Building",
                                                          "70 (user-defined)"]
    assert fig.axes == []  # no colour bar
    image = rn.render(points, codes, field="classification", view=TOP, size=SIZE)
    drawing = image[:, : int(0.8 * SIZE[0])]
    for code, share in ((2, 0.45), (6, 0.45)):
        colour = hex255(colours.CLASS_COLOURS[code])
        assert near_colour(drawing, colour).sum() > share * 0.85 * drawn(drawing).sum()


def test_points_drawn_grey_are_named_under_the_colour_bar():
    """A scalar field's NaN points are grey; ``missing`` names them in a legend entry where
    there are any, and the colour bar keeps its place above it."""
    points = square_cloud()
    values = points[:, 0].copy()
    values[points[:, 0] < 0.5] = np.nan
    fig = rn.figure(points, values, field="displacement", view=TOP, size=SIZE,
                    missing="other classes, kept in place")
    legend, = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["other classes, kept in place"]
    assert np.allclose(legend.legend_handles[0].get_facecolor()[:3], rn.NAN_GREY)
    bar, = fig.axes
    assert bar.get_position().y0 > legend.get_window_extent().y0 / SIZE[1]
    image = rn.render(points, values, field="displacement", view=TOP, size=SIZE)
    drawing = image[:, : int(0.8 * SIZE[0])]
    grey = np.rint(np.asarray(rn.NAN_GREY) * 255).astype(int)
    assert near_colour(drawing, grey).sum() > 0.4 * drawn(drawing).sum()
    assert rn.figure(points, points[:, 0], field="displacement", size=SIZE,
                     missing="kept").legends == []


def test_a_legend_of_many_classes_names_the_most_numerous():
    points = square_cloud()
    codes = np.arange(len(points)) % 25  # 25 classes, 0-15 one point more than 16-24
    fig = rn.figure(points, codes, field="classification", size=SIZE)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert len(labels) == rn.LEGEND_ROWS
    assert labels[:2] == ["0 Never classified", "1 Unclassified"]
    assert labels[-1] == f"+{25 - rn.LEGEND_ROWS + 1} other classes"


@pytest.mark.parametrize("bad, match", [(np.full(1600, 2.5), "whole class numbers"),
                                        (np.full(1600, 300), "0-255")])
def test_classification_must_be_class_numbers(bad, match):
    with pytest.raises(ValueError, match=match):
        rn.render(square_cloud(), bad, field="classification", size=SIZE)


def test_intensity_is_grey_between_its_2nd_and_98th_percentiles():
    points = square_cloud()
    intensity = (np.arange(len(points)) * 37 % 1000).astype(np.uint16)
    intensity[:8] = 60000  # a few hot returns must not wash out the rest
    fig = rn.figure(points, intensity, field="intensity", view=TOP, size=SIZE)
    bar, = fig.axes
    assert bar.get_ylabel() == "intensity"
    assert bar.get_ylim() == pytest.approx(tuple(np.percentile(intensity, [2, 98])))
    image = left_part(rn.render(points, intensity, field="intensity", view=TOP, size=SIZE))
    rgb = image[drawn(image)][:, :3].astype(int)
    assert (np.ptp(rgb, axis=1) <= 1).all()  # grey
    assert rgb[:, 0].max() - rgb[:, 0].min() > 150  # the whole ramp, not one washed-out grey


@pytest.mark.parametrize("dtype, scale", [(np.uint8, 1), (np.uint16, 257), (np.uint16, 1),
                                          (np.float64, 1 / 255)])
def test_rgb_is_drawn_as_stored_8_or_16_bit(dtype, scale):
    points = square_cloud()
    left = points[:, 0] < 0.5
    rgb = np.where(left[:, None], [200, 100, 50], [20, 180, 240]) * scale
    fig = rn.figure(points, rgb.astype(dtype), view=TOP, size=SIZE)
    assert fig.axes == [] and fig.legends == []
    image = rn.render(points, rgb.astype(dtype), view=TOP, size=SIZE)
    assert near_colour(image, (200, 100, 50)).sum() > 0.4 * drawn(image).sum()
    assert near_colour(image, (20, 180, 240)).sum() > 0.4 * drawn(image).sum()


@pytest.mark.parametrize("units, label", [("ft", "displacement (ft)"),
                                          (None, "displacement (coordinate units)")])
def test_displacement_has_a_labelled_bar_in_the_file_s_units(units, label):
    points = square_cloud()
    moved = np.random.default_rng(2).exponential(0.05, len(points))  # metres, say
    fig = rn.figure(points, moved, field="displacement", units=units, size=SIZE)
    bar, = fig.axes
    assert bar.get_ylabel() == label
    assert bar.get_ylim() == pytest.approx((0.0, np.percentile(moved, 98)))
    assert "height (ft)" == rn.figure(points, points[:, 1], field="height", units="ft",
                                      size=SIZE).axes[0].get_ylabel()


def test_the_docs_call_draws_a_picture(tmp_path):
    import re

    import pssd_fast  # noqa: F401 (the docs' call names it)

    readme = (Path(__file__).resolve().parent.parent / "docs" / "architecture.md").read_text()
    call = 'pssd_fast.pictures.render(points, result.displacement, "moved.png", ' \
        'field="displacement")'
    assert call in re.sub(r"\s+", " ", readme)
    points = square_cloud()
    result = SimpleNamespace(displacement=np.linspace(0.0, 1.0, len(points)))  # noqa: F841
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        image = eval(call)
    finally:
        os.chdir(here)
    assert image.ndim == 3 and (tmp_path / "moved.png").is_file()


def write_las(path, *wkts):
    """A small LAS 1.4 file with a WKT VLR per string of ``wkts``."""
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=6, version="1.4")
    for wkt in wkts:
        header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(wkt))
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.arange(10.0), np.arange(10.0), np.zeros(10)
    las.write(path)
    return path


@pytest.mark.parametrize("wkts, expected", [
    ((), None),
    (('PROJCS["a",GEOGCS["g",UNIT["degree",0.0174532925199433]],UNIT["metre",1]]',), "m"),
    (('PROJCRS["a",CS[Cartesian,2],LENGTHUNIT["US survey foot",0.304800609601219]]',),
     "US ft"),
    (('COMPD_CS["a",PROJCS["p",UNIT["metre",1]],VERT_CS["v",UNIT["foot",0.3048]]]',), None),
])
def test_the_units_of_a_las_file_come_from_its_coordinate_system(tmp_path, wkts, expected):
    from pssd_fast import io
    from pssd_fast.pictures.fields import units

    assert units(io.read(write_las(tmp_path / "u.las", *wkts))) == expected
    assert units(io.PointCloud(points=np.zeros((3, 3)))) is None


def test_the_airborne_survey_is_in_feet():
    """The shared Autzen file says feet twice: its GeoTIFF keys (ProjLinearUnits 9002) and its
    WKT (UNIT["foot",0.3048])."""
    from pssd_fast import io
    from pssd_fast.pictures.fields import units

    from .conftest import data_file

    pytest.importorskip("laspy")
    assert units(io.read(data_file("lidar", "autzen_trim.laz"))) == "ft"


def test_a_missing_field_is_refused_with_what_the_cloud_has():
    from pssd_fast.pictures.fields import field_values

    points = square_cloud()
    stored = {"Intensity": np.ones(len(points), np.uint16)}
    with pytest.raises(ValueError, match=r"holds no classification; colour it by height, "
                                         r"curvature, likelihood, feature, intensity \(its "
                                         r"per-point fields: Intensity\)"):
        field_values("classification", points, stored=stored)
    np.testing.assert_array_equal(field_values("intensity", points, stored=stored), 1.0)


def test_render_s_example_runs():
    import doctest

    from pssd_fast import pictures

    runner = doctest.DocTestRunner()
    for test in doctest.DocTestFinder().find(pictures.render, "render", globs={}):
        runner.run(test)
    assert runner.tries >= 3 and runner.failures == 0
