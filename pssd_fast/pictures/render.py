"""Pictures of a point cloud coloured by a per-point field (the optional ``viz`` extra).

The points are drawn by a small splatter of this module's own, in numpy: an orthographic
projection after rotating by the view, a z-buffer, and one disc per point whose size follows the
cloud's spacing on screen, so that a sampled surface looks closed. Matplotlib (imported lazily,
through the Agg canvas only, never pyplot) maps values to colours and composes the final picture
with a colour bar and a title.

Views are ``(elevation, azimuth)`` in degrees about the cloud's *up* axis (``"z"`` unless
``up`` says otherwise). With ``z`` up: ``(0, 0)`` looks along ``+y`` (``x`` to the right, ``z``
up), a positive azimuth turns the camera counter-clockwise about ``z`` seen from above
(``(0, 90)`` looks along ``-x``), and a positive elevation raises it above the ``xy`` plane.
Another up axis is first turned to ``z`` by a rotation: ``"y"`` by +90 degrees about ``x``
(``y`` to ``z``, ``z`` to ``-y``: a model facing ``+z``, as y-up models do, faces the default
view), ``"x"`` by the cyclic exchange that makes ``x`` the new ``z`` (and ``y`` the new
``x``). :func:`choose_up` picks one from the data.

Each field has one colour map and one fixed range (:data:`STYLES`), shared by ``pssd render``,
``pssd demo`` and :func:`figure_set`, so pictures meant to be compared use one scale.
"""
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple, Optional

import numpy as np

from .. import atomic
from .._validation import as_normals, as_points, check_float, check_int

__all__ = ["COLOR_FIELDS", "DEFAULT_VIEW", "IMAGE_FORMATS", "STYLES", "UP_AXES", "Style",
           "bounding_frame", "choose_up", "figure_set", "height", "render"]

#: Per-point fields a picture can be coloured by (the choices offered to tools).
COLOR_FIELDS = ("likelihood", "feature", "curvature", "displacement", "height")


class Style(NamedTuple):
    """Colour map, colour limits (None: from the data) and colour-bar label of a field."""

    cmap: str
    vmin: Optional[float]
    vmax: Optional[float]
    label: str


#: Style of each field, in the units of :func:`pssd_fast.pictures.fields.field_values`. Feature
#: intensity and likelihood lie in [0, 1] by definition. Curvature times the diagonal: +-50
#: shows the noise of a raw scan (median |H| d is 28 on the CAD part at 0.25% noise, 8 on
#: Igea's vertices) and how much denoising removes (4 on the denoised part) while sharp edges
#: (150 and more) saturate. Displacement over the diagonal: 0 to 1%, four times the demo's
#: noise. Height: the coordinate along the up axis, 1st to 99th percentile of the cloud.
STYLES = {
    "feature": Style("YlOrRd", 0.0, 1.0, "feature intensity"),
    "likelihood": Style("viridis", 0.0, 1.0, "sampling likelihood"),
    "curvature": Style("RdBu_r", -50.0, 50.0, "mean curvature x diagonal"),
    "displacement": Style("plasma", 0.0, 0.01, "displacement / diagonal"),
    "height": Style("cividis", None, None, "height"),
}
#: Axes that can point up in a picture.
UP_AXES = ("x", "y", "z")
# Rotation of each up axis to z (rows: the new x, y, z in the cloud's coordinates).
_TO_Z_UP = {"z": np.eye(3),
            "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
            "x": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])}
# choose_up: a cloud whose least extent is under this fraction of its largest is flat (a
# terrain, a facade, a plate) and is seen from the side of its least extent.
FLAT_EXTENT = 1.0 / 3.0
#: Picture formats by file extension (lower case); matplotlib writes PNG, Pillow the others.
IMAGE_FORMATS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff",
                 ".tiff": "tiff", ".webp": "webp"}
#: ``(elevation, azimuth)`` in degrees: from above, in front and to the left.
DEFAULT_VIEW = (30.0, -60.0)
DEFAULT_SIZE = (1000, 800)

# Fraction of the light that reaches surfaces seen edge-on, so they stay readable.
AMBIENT = 0.25
PLAIN_GREY = (0.8, 0.8, 0.8)   # colour of every point when no values are given
NAN_GREY = (0.5, 0.5, 0.5)     # colour of NaN values, darker than PLAIN_GREY
# Radius within which a point can colour a pixel, in mean point spacings: on a randomly
# (Poisson) sampled surface exp(-pi 1.5^2) = 0.1 % of the pixels lie farther from every point
# and take a neighbour's point instead.
REACH_PER_SPACING = 1.5
# The depth map is closed over this many reaches (3 spacings): discs of radius c spacings leave
# exp(-pi c^2) of a randomly sampled surface uncovered, 5e-13 at c = 3, so the back of a closed
# surface never shows through its gaps.
CLOSE_PER_REACH = 2.0
# Outlines end this many reaches (half a spacing) beyond the outermost points.
OUTLINE_PER_REACH = 1.0 / 3.0
# Depth tolerance of the visible surface, in reaches (turned into depth by the scale): covers
# the depth a tilted surface spans within one reach.
TOLERANCE_PER_REACH = 2.0
DENSITY_SAMPLE = 20000         # points used to estimate the density (a kd-tree over all costs more)
MAX_RADIUS_FRACTION = 0.05     # cap on the disc radius, as a fraction of the picture's short side
FILL = 0.95                    # fraction of the picture's short side the bounding sphere spans
VIZ_HINT = "pip install 'pssd_fast[viz]'"


def _matplotlib():
    """Import what the pictures need from matplotlib, or say how to install it."""
    try:
        from matplotlib import colormaps
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize, to_rgba
        from matplotlib.figure import Figure
        from matplotlib.image import imsave
    except ImportError as exc:
        raise ImportError(f"pssd_fast.pictures.render needs matplotlib (the optional 'viz' extra): "
                          f"{VIZ_HINT}") from exc
    return SimpleNamespace(colormaps=colormaps, FigureCanvasAgg=FigureCanvasAgg,
                           ScalarMappable=ScalarMappable, Normalize=Normalize, to_rgba=to_rgba,
                           Figure=Figure, imsave=imsave)


def _check_view(view):
    """Return ``view`` as finite ``(elevation, azimuth)`` floats."""
    if isinstance(view, (str, bytes)) or not hasattr(view, "__len__") or len(view) != 2:
        raise TypeError(f"view must be a pair (elevation, azimuth) in degrees; got {view!r}")
    return (check_float(view[0], "view elevation"), check_float(view[1], "view azimuth"))


def _check_up(up):
    if up not in UP_AXES:
        raise ValueError(f"up must be one of {', '.join(UP_AXES)}; got {up!r}")
    return up


def _basis(view, up="z"):
    """Rows ``right, up, towards the viewer`` of the camera for ``(elevation, azimuth)`` about
    the ``up`` axis, in the cloud's coordinates."""
    elev, azim = np.radians(_check_view(view))
    ce, se, ca, sa = np.cos(elev), np.sin(elev), np.cos(azim), np.sin(azim)
    right = [ca, sa, 0.0]
    screen_up = [-se * sa, se * ca, ce]
    eye = [ce * sa, -ce * ca, se]
    return np.array([right, screen_up, eye]) @ _TO_Z_UP[_check_up(up)]


def choose_up(points, georeferenced=False):
    """The axis that points up in a picture of ``points`` when none is given.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates.
    georeferenced : bool, default False
        True for LAS/LAZ data, whose ``z`` is elevation by definition.

    Returns
    -------
    {"x", "y", "z"}
        ``"z"`` for georeferenced data; else, for a flat cloud (least bounding-box extent under
        a third of the largest: a terrain, a facade, a plate), the axis of its least extent, so
        that it is seen from above; else ``"y"``, the convention of scanned models and mesh
        formats (the Stanford and Cyberware scans, OBJ and PLY tools), under which Igea, the
        bunny and the dragon stand upright.
    """
    if georeferenced:
        return "z"
    pts, _ = as_points(points)
    extent = pts.max(axis=0) - pts.min(axis=0)
    least = int(np.argmin(extent))
    return UP_AXES[least] if extent[least] < FLAT_EXTENT * extent.max() else "y"


def height(points, up="z"):
    """Coordinate of each point along the up axis, for the ``"height"`` colouring.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates.
    up : {"x", "y", "z"}, default "z"
        The cloud's up axis.

    Returns
    -------
    (n,) float64
        The ``up`` coordinate (elevation, for a terrain): whatever the view, larger values lie
        higher.
    """
    pts, _ = as_points(points)
    return pts[:, UP_AXES.index(_check_up(up))].copy()


def bounding_frame(points):
    """Centre and radius of the sphere about the bounding-box centre that holds every point.

    Pass one frame to :func:`render` for several clouds (a noisy scan and its denoised copy) so
    that their pictures line up; the frame does not depend on the view, so neither does the
    scale of the picture.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates, at least one point.

    Returns
    -------
    centre : (3,) float64
    radius : float
        Positive (1 for a single location).
    """
    pts, _ = as_points(points)
    if pts.shape[0] == 0:
        raise ValueError("points is empty: a frame needs at least one point")
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    radius = float(np.sqrt(((pts - centre) ** 2).sum(axis=1).max()))
    return centre, radius if radius > 0.0 else 1.0


def _check_frame(frame):
    centre = np.asarray(frame[0], dtype=np.float64)
    if centre.shape != (3,) or not np.isfinite(centre).all():
        raise ValueError(f"frame centre must be 3 finite numbers; got {frame[0]!r}")
    return centre, check_float(frame[1], "frame radius", positive=True)


def _check_size(size):
    if isinstance(size, (str, bytes)) or not hasattr(size, "__len__") or len(size) != 2:
        raise TypeError(f"size must be a pair (width, height) in pixels; got {size!r}")
    return check_int(size[0], "width", minimum=64), check_int(size[1], "height", minimum=64)


def _as_values(values, n, name="values"):
    """Return ``values`` as ``(n,) float64`` (NaN allowed: drawn grey)."""
    arr = np.asarray(values)
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name} must hold real numbers; got dtype {arr.dtype}")
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), one value per point; got shape "
                         f"{arr.shape}")
    return arr.astype(np.float64)


def _robust_limits(values, vmin, vmax):
    """``vmin``/``vmax`` where given, else the 1st/99th percentiles of the finite values."""
    vmin = None if vmin is None else check_float(vmin, "vmin")
    vmax = None if vmax is None else check_float(vmax, "vmax")
    if vmin is not None and vmax is not None and vmax < vmin:
        raise ValueError(f"vmin must not exceed vmax; got vmin={vmin}, vmax={vmax}")
    if vmin is None or vmax is None:
        finite = values[np.isfinite(values)]
        low, high = np.percentile(finite, [1.0, 99.0]).tolist() if finite.size else (0.0, 1.0)
        # A limit given on one side wins over the percentile on the other.
        if vmin is None:
            vmin = low if vmax is None else min(low, vmax)
        if vmax is None:
            vmax = max(high, vmin)
    if vmax == vmin:  # a constant field: widen so it maps to the colormap's middle
        vmin, vmax = vmin - 0.5, vmax + 0.5
    return vmin, vmax


def _spacing(points):
    """Mean point spacing ``1 / sqrt(density)`` on the sampled surface, or 0 if unknown.

    The nearest-neighbour distance of a random subsample of ``m`` out of ``n`` points is
    ``sqrt(n / m)`` times that of the whole cloud (thinning a surface sampling scales its density
    by ``m / n``), and for random sampling the mean nearest-neighbour distance is half the
    spacing.
    """
    from .._threads import kdtree

    n = points.shape[0]
    if n < 2:
        return 0.0
    m = min(n, DENSITY_SAMPLE)
    sample = points[np.random.default_rng(0).choice(n, m, replace=False)] if m < n else points
    distance, _ = kdtree(sample).query(sample, k=2)
    return 2.0 * float(np.mean(distance[:, 1])) * np.sqrt(m / n)


def _disc(radius):
    """Integer pixel offsets ``(dy, dx)`` of a disc of ``radius`` pixels (one pixel if < 1)."""
    reach = int(np.floor(radius))
    dy, dx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    inside = dy**2 + dx**2 <= radius**2
    return dy[inside], dx[inside]


def _splat(screen, depth, reach, tolerance, shape):
    """Index of the point seen at each pixel (-1 for none).

    A closing of the depth map finds the visible surface: the nearest depth within
    ``CLOSE_PER_REACH * reach`` of each pixel (wide enough to bridge every gap of a randomly
    sampled surface), then the farthest of those within a slightly smaller radius (so that
    outlines end ``OUTLINE_PER_REACH * reach`` beyond the outermost points instead of spilling
    over the background or a farther surface). Each pixel of the surface goes to the point
    nearest on screen, within ``reach``, among those no farther than ``tolerance`` behind it;
    the rare pixels with none take a neighbour's point. The surface is thus a mosaic of its
    own points: colours are not blurred, and points behind it never show.

    Parameters
    ----------
    screen : (n, 2) float64
        ``(column, row)`` of each point in pixels, row 0 at the top; points outside the
        picture are not drawn.
    depth : (n,) float64
        Larger is nearer the viewer.
    reach : float
        Radius in pixels within which a point can colour a pixel.
    tolerance : float
        Depth within which points count as the same surface, in ``depth``'s units.
    shape : (int, int)
        ``(height, width)`` of the picture.

    Returns
    -------
    (height, width) intp
    """
    h, w = shape
    col = np.floor(screen[:, 0]).astype(np.intp)
    row = np.floor(screen[:, 1]).astype(np.intp)
    kept = np.flatnonzero((col >= 0) & (col < w) & (row >= 0) & (row < h))
    close = CLOSE_PER_REACH * reach
    shrink = close - OUTLINE_PER_REACH * reach
    # A border wide enough for both filters and for every disc, so nothing needs bounds checks.
    pad = int(np.ceil(close + shrink)) + 1
    stride = w + 2 * pad
    centre = (row[kept] + pad) * stride + (col[kept] + pad)
    z = depth[kept]
    nearest = np.full((h + 2 * pad) * stride, -np.inf)
    np.maximum.at(nearest, centre, z)
    nearest = nearest.reshape(h + 2 * pad, stride)
    surface = _disc_filter(_disc_filter(nearest, close, np.maximum), shrink, np.minimum)
    drawn = surface[pad:pad + h, pad:pad + w] > -np.inf
    # +inf outside the picture: no point passes the depth test there.
    surface[:pad], surface[pad + h:], surface[:, :pad], surface[:, pad + w:] = (np.inf,) * 4
    surface = surface.ravel()
    # Key: squared distance from the point to the pixel's centre (in 1/256 pixel^2) in the high
    # bits, the point in the low 32, so that np.minimum.at picks the nearest point whatever the
    # order of the writes (exact ties, rare at this resolution, go to the lowest index).
    fx = col[kept] + 0.5 - screen[kept, 0]
    fy = row[kept] + 0.5 - screen[kept, 1]
    best = np.full(surface.size, np.iinfo(np.int64).max)
    dy, dx = _disc(reach)
    for oy, ox in zip(dy, dx, strict=True):
        pixel = centre + (oy * stride + ox)
        near = np.flatnonzero(z >= surface[pixel] - tolerance)
        distance2 = np.rint(256.0 * ((fx[near] + ox) ** 2 + (fy[near] + oy) ** 2))
        np.minimum.at(best, pixel[near], (distance2.astype(np.int64) << 32) | near)
    best = best.reshape(h + 2 * pad, stride)[pad:pad + h, pad:pad + w]
    seen = np.full((h, w), -1, dtype=np.intp)
    found = drawn & (best != np.iinfo(np.int64).max)
    seen[found] = kept[best[found] & 0xFFFFFFFF]
    return _fill(seen, drawn, int(np.ceil(close - reach)) + 1)


def _fill(seen, drawn, steps):
    """Give the pixels of ``drawn`` still without a point (-1 in ``seen``) a neighbour's point,
    growing ``steps`` pixels at most."""
    h, w = seen.shape
    for _ in range(steps):
        missing = drawn & (seen < 0)
        if not missing.any():
            break
        padded = np.pad(seen, 1, constant_values=-1)
        for oy, ox in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)):
            source = padded[1 + oy:1 + oy + h, 1 + ox:1 + ox + w]
            take = missing & (source >= 0)
            seen[take] = source[take]
            missing &= ~take
    return seen


def _disc_filter(image, radius, reduce):
    """``reduce`` (``np.minimum`` or ``np.maximum``) of ``image`` over the disc of ``radius``
    pixels about each pixel; the disc is cut at the image's edges.

    Each row of the disc is a horizontal window; windows grow one pixel a side at a time, so
    the cost is about ``3 * radius`` passes over the image instead of one per disc pixel.
    """
    h = image.shape[0]
    reach = int(np.floor(radius))
    out = image.copy()
    window, half = image, 0  # reduction over a horizontal window of 2 * half + 1 pixels
    for oy in sorted(range(-reach, reach + 1), key=abs, reverse=True):
        while half < int(np.floor(np.sqrt(radius**2 - oy**2))):
            grown = window.copy()
            reduce(grown[:, 1:], window[:, :-1], out=grown[:, 1:])
            reduce(grown[:, :-1], window[:, 1:], out=grown[:, :-1])
            window, half = grown, half + 1
        if oy >= 0:
            reduce(out[:h - oy], window[oy:], out=out[:h - oy])
        else:
            reduce(out[-oy:], window[:h + oy], out=out[-oy:])
    return out


def _layout(width, height_px, colour_bar, title):
    """Pixel boxes of the splat and the colour bar, and the title's height, for the figure."""
    margin = max(4, round(0.02 * min(width, height_px)))
    title_band = round(0.07 * height_px) if title else 0
    bar_band = round(0.17 * width) if colour_bar else 0
    splat = (margin, margin, width - 2 * margin - bar_band, height_px - 2 * margin - title_band)
    bar = (width - bar_band + round(0.02 * width), margin + round(0.1 * splat[3]),
           max(6, round(0.025 * width)), round(0.8 * splat[3]))
    return splat, bar, title_band


def render(points, values=None, path=None, *, field=None, view=DEFAULT_VIEW, up="z",
           normals=None, cmap=None, vmin=None, vmax=None, label=None, title=None,
           size=DEFAULT_SIZE, point_size=None, background="white", frame=None):
    """Draw a point cloud coloured by a per-point field; optionally write it to a file.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates.
    values : array_like, shape (n,), optional
        Field to colour by; NaN values are drawn grey. Without values every point is light grey
        and no colour bar is drawn.
    path : str or os.PathLike, optional
        Picture to write, in the format of its extension (:func:`image_format`), atomically:
        a temporary file in the same folder, then renamed.
    field : str, optional
        A key of :data:`STYLES` (``"feature"``, ``"curvature"``...): its colour map, limits and
        label are the defaults of ``cmap``, ``vmin``, ``vmax`` and ``label``, so pictures of a
        field share one scale. ``values`` must then be in the units of
        :func:`pssd_fast.pictures.fields.field_values`.
    view : (float, float), default (30, -60)
        ``(elevation, azimuth)`` in degrees (see the module docstring).
    up : {"x", "y", "z"}, default "z"
        The cloud's axis drawn upwards (:func:`choose_up` picks one from the data).
    normals : array_like, shape (n, 3), optional
        Normals for Lambert shading under a light at the camera (a headlight), flipped to face
        the viewer so their orientation does not matter. Without them nothing is shaded.
    cmap : str or matplotlib.colors.Colormap, optional
        Colormap for ``values``; default the field's, else "viridis".
    vmin, vmax : float, optional
        Colour limits; default the field's, else the 1st and 99th percentiles of the finite
        values, so a few outliers do not wash out the rest. Values beyond them take the end
        colours (and the colour bar shows an arrow).
    label : str, optional
        Label of the colour bar; default the field's.
    title : str, optional
        Title above the picture.
    size : (int, int), default (1000, 800)
        ``(width, height)`` of the picture in pixels, each at least 64.
    point_size : float, optional
        Diameter in pixels of the disc each point may colour; by default 3 mean point spacings
        on screen, capped at a tenth of the picture's short side.
    background : matplotlib colour, default "white"
    frame : (array_like (3,), float), optional
        ``(centre, radius)`` of the sphere fitted to the picture's short side; default
        :func:`bounding_frame` of ``points``. Give clouds one frame to make pictures line up.

    Returns
    -------
    (height, width, 4) uint8
        The RGBA picture, as written to ``path``.

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    TypeError, ValueError
        If an argument has the wrong type, shape or value.

    Notes
    -----
    The projection is orthographic and its scale depends only on ``frame``, not on ``view``.
    A closing of the z-buffer finds the visible surface, so nearer points hide farther ones
    and a randomly sampled surface shows no gaps; each of its pixels shows the nearest of its
    points on screen (a mosaic: the discs' overlap does not blur colours). Points outside the
    picture are not drawn. One million points take a few seconds at most.
    """
    mpl = _matplotlib()
    if path is not None:
        image_type = image_format(path)
    if field is not None:
        if field not in STYLES:
            raise ValueError(f"field must be one of {', '.join(STYLES)}; got {field!r}")
        style = STYLES[field]
        cmap = style.cmap if cmap is None else cmap
        vmin = style.vmin if vmin is None else vmin
        vmax = style.vmax if vmax is None else vmax
        label = style.label if label is None else label
    pts, _ = as_points(points)
    n = pts.shape[0]
    basis = _basis(view, up)
    width, height_px = _check_size(size)
    vals = None if values is None else _as_values(values, n)
    nrm = None if normals is None else as_normals(normals, n)
    centre, radius = bounding_frame(pts) if frame is None else _check_frame(frame)
    if point_size is not None:
        point_size = check_float(point_size, "point_size", positive=True)
    if vals is not None:
        colormap = mpl.colormaps.get_cmap("viridis" if cmap is None else cmap)
        norm = mpl.Normalize(*_robust_limits(vals, vmin, vmax), clip=True)
    background_rgba = np.array(mpl.to_rgba(background))

    (x0, y0, w, h), bar_box, title_band = _layout(width, height_px, vals is not None, title)
    scale = FILL * min(w, h) / (2.0 * radius)
    camera = (pts - centre) @ basis.T
    screen = np.column_stack([0.5 * w + scale * camera[:, 0], 0.5 * h - scale * camera[:, 1]])
    if point_size is None:
        reach = REACH_PER_SPACING * _spacing(pts) * scale
    else:
        reach = 0.5 * point_size
    reach = min(reach, MAX_RADIUS_FRACTION * min(w, h))
    seen = _splat(screen, camera[:, 2], reach, TOLERANCE_PER_REACH * max(reach, 1.0) / scale,
                  (h, w))

    hit = seen >= 0
    who = seen[hit]
    if vals is None:
        rgb = np.broadcast_to(np.array(PLAIN_GREY), (who.size, 3))
    else:
        shown = vals[who]
        rgb = colormap(norm(np.nan_to_num(shown, nan=norm.vmin)))[:, :3]
        rgb[np.isnan(shown)] = NAN_GREY
    if nrm is not None:
        light = AMBIENT + (1.0 - AMBIENT) * np.abs(nrm[who] @ basis[2])
        rgb = rgb * light[:, None]
    image = np.empty((h, w, 4))
    image[:] = background_rgba
    image[hit, :3] = rgb
    image[hit, 3] = 1.0

    fig = mpl.Figure(figsize=(width / 100.0, height_px / 100.0), dpi=100,
                     facecolor=background_rgba)
    canvas = mpl.FigureCanvasAgg(fig)
    # figimage places the buffer pixel for pixel (no resampling); yo counts from the bottom.
    fig.figimage(image, xo=x0, yo=y0, origin="upper")
    font = max(6.0, 12.0 * min(width, height_px) / 800.0)
    if vals is not None:
        finite = vals[np.isfinite(vals)]
        below = finite.size > 0 and finite.min() < norm.vmin
        above = finite.size > 0 and finite.max() > norm.vmax
        extend = ("both" if above else "min") if below else ("max" if above else "neither")
        bx, by, bw, bh = bar_box
        cax = fig.add_axes((bx / width, by / height_px, bw / width, bh / height_px))
        bar = fig.colorbar(mpl.ScalarMappable(norm=norm, cmap=colormap), cax=cax, extend=extend)
        bar.ax.tick_params(labelsize=0.85 * font)
        if label:
            bar.set_label(label, fontsize=font)
    if title:
        fig.text(0.5, 1.0 - 0.5 * title_band / height_px, title, ha="center", va="center",
                 fontsize=1.2 * font)
    canvas.draw()
    picture = np.array(canvas.buffer_rgba(), dtype=np.uint8)
    if path is not None:
        _write_image(path, picture, image_type, mpl.imsave)
    return picture


def image_format(path):
    """The picture format that the extension of ``path`` asks for.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    str
        A value of :data:`IMAGE_FORMATS`: ``"png"``, ``"jpeg"`` (``.jpg``, ``.jpeg``),
        ``"tiff"`` or ``"webp"``.

    Raises
    ------
    ValueError
        If the extension is missing or not one of :data:`IMAGE_FORMATS` (case-insensitive).
    """
    path = Path(path)
    kind = IMAGE_FORMATS.get(path.suffix.lower())
    if kind is None:
        what = f"extension {path.suffix!r}" if path.suffix else "no extension"
        raise ValueError(f"{path}: cannot write a picture with {what}; supported: "
                         f"{', '.join(IMAGE_FORMATS)}")
    return kind


def _write_image(path, picture, kind, imsave):
    """Write ``picture`` to ``path`` as ``kind``, whole or not at all
    (:func:`pssd_fast.atomic.replacing`)."""
    with atomic.replacing(path) as f:
        imsave(f, picture, format=kind)


def figure_set(folder, noisy, denoised, *, likelihood, feature, displacement,
               normals_noisy=None, normals_denoised=None, view=DEFAULT_VIEW, up="z",
               size=DEFAULT_SIZE):
    """Write the paper's set of pictures of one denoising run as PNGs into ``folder``.

    Parameters
    ----------
    folder : str or os.PathLike
        Output folder, created if missing; existing pictures of the same names are replaced.
    noisy, denoised : array_like, shape (n, 3)
        The input and the output, point for point.
    likelihood : array_like, shape (n,)
        Sampling likelihood (:attr:`DenoiseResult.likelihood`).
    feature : array_like, shape (n,)
        Feature intensity in ``[0, 1]`` (:attr:`DenoiseResult.feature_intensity`).
    displacement : array_like, shape (n,)
        ``|p_noisy - p_denoised|`` in the points' units (:attr:`DenoiseResult.displacement`).
    normals_noisy, normals_denoised : array_like, shape (n, 3), optional
        Normals for the shading; by default estimated with :func:`pssd_fast.estimate_normals`.
    view : (float, float), default (30, -60)
        ``(elevation, azimuth)`` in degrees.
    up : {"x", "y", "z"}, default "z"
        The clouds' up axis.
    size : (int, int), default (1000, 800)
        ``(width, height)`` of each picture in pixels.

    Returns
    -------
    list of pathlib.Path
        ``noisy.png`` (the input, shaded grey), ``curvature.png`` (the input's mean curvature),
        ``likelihood.png``, ``feature.png`` (both drawn on the input, as ``pssd render`` draws
        them), ``denoised_curvature.png`` and ``denoised_displacement.png``, in that order.

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    TypeError, ValueError
        If an argument has the wrong type or shape.

    Notes
    -----
    Every picture uses the input's :func:`bounding_frame`, so all six line up, and the field's
    :data:`STYLES`, as ``pssd render`` does: the curvature pictures of the input and the
    output (:func:`pssd_fast.pictures.fields.curvature` of each) share one scale, and each picture
    equals what ``pssd render`` draws for the same field of the same points.
    """
    from .fields import curvature, diagonal
    from ..stages import estimate_normals

    _matplotlib()  # fail before any work when matplotlib is missing
    noisy_pts, _ = as_points(noisy, "noisy")
    denoised_pts, _ = as_points(denoised, "denoised")
    n = noisy_pts.shape[0]
    if denoised_pts.shape[0] != n:
        raise ValueError(f"denoised must have one row per input point: got "
                         f"{denoised_pts.shape[0]} rows for {n} points")
    fields = {name: _as_values(v, n, name) for name, v in (
        ("likelihood", likelihood), ("feature", feature), ("displacement", displacement))}
    nrm_in = (estimate_normals(noisy_pts) if normals_noisy is None
              else as_normals(normals_noisy, n, "normals_noisy"))
    nrm_out = (estimate_normals(denoised_pts) if normals_denoised is None
               else as_normals(normals_denoised, n, "normals_denoised"))

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    common = {"view": view, "up": up, "size": size, "frame": bounding_frame(noisy_pts)}
    pictures = [
        ("noisy.png", noisy_pts, nrm_in, None, None, "Input"),
        ("curvature.png", noisy_pts, nrm_in, curvature(noisy_pts), "curvature",
         "Input: mean curvature"),
        ("likelihood.png", noisy_pts, nrm_in, fields["likelihood"], "likelihood",
         "Input: sampling likelihood"),
        ("feature.png", noisy_pts, nrm_in, fields["feature"], "feature",
         "Input: feature intensity"),
        ("denoised_curvature.png", denoised_pts, nrm_out, curvature(denoised_pts), "curvature",
         "Denoised: mean curvature"),
        ("denoised_displacement.png", denoised_pts, nrm_out,
         fields["displacement"] / diagonal(denoised_pts), "displacement",
         "Denoised: displacement"),
    ]
    paths = []
    for name, pts, nrm, vals, field, title in pictures:
        render(pts, vals, folder / name, field=field, normals=nrm, title=title, **common)
        paths.append(folder / name)
    return paths
