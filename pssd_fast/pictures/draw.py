"""Pictures of a point cloud coloured by a per-point field (the optional ``viz`` extra).

The points are drawn by the splatter of :mod:`.splat`, in numpy: an orthographic projection
after rotating by the view (:mod:`.view`), a z-buffer, and one disc per point whose size follows
the cloud's spacing on screen, so that a sampled surface looks closed. Matplotlib (imported
lazily, through the Agg canvas only, never pyplot) maps values to colours (:mod:`.colours`) and
composes the picture with its key (a colour bar or a legend of classes) and a title.

Each scalar field has one colour map and one range rule (:data:`STYLES`), shared by ``pssd
render``, ``pssd demo`` and :func:`figure_set`, so pictures meant to be compared use one scale.
"""
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .. import atomic
from .._validation import as_normals, as_points, check_float, check_int
from . import splat as splatter
from .colours import INTENSITY_TOP, ROBUST_PERCENTILES, STYLES, class_colours, class_name, \
    rgb_colours
from .view import DEFAULT_VIEW, basis, check_view, choose_view, fit

__all__ = ["COLOR_FIELDS", "DEFAULT_SIZE", "IMAGE_FORMATS", "figure", "figure_set",
           "image_format", "render"]

#: What a picture can be coloured by: the scalar fields of :data:`STYLES` (a colour bar), the
#: LiDAR classes (a legend) and the file's own colours.
COLOR_FIELDS = ("height", "classification", "intensity", "rgb", "likelihood", "feature",
                "curvature", "displacement")
#: Picture formats by file extension (lower case); matplotlib writes PNG, Pillow the others.
IMAGE_FORMATS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff",
                 ".tiff": "tiff", ".webp": "webp"}
#: ``(width, height)`` in pixels; a height of None follows the cloud (:func:`figure`).
DEFAULT_SIZE = (1000, None)
#: The widest and tallest picture in pixels: 8192 x 8192 takes a quarter of a gigabyte a
#: layer, and matplotlib draws several.
LARGEST = 8192
# Bounds of a free height: the drawing at most 1.25 times as high as wide (a standing figure),
# the picture at least 0.3 times as high as wide (room for the key and the title).
TALLEST = 1.25
FLATTEST = 0.3

# Fraction of the light that reaches surfaces seen edge-on, so they stay readable.
AMBIENT = 0.25
PLAIN_GREY = (0.8, 0.8, 0.8)   # colour of every point when no values are given
NAN_GREY = (0.5, 0.5, 0.5)     # colour of NaN values, darker than PLAIN_GREY
MAX_RADIUS_FRACTION = 0.05     # cap on the disc radius, as a fraction of the picture's short side
# Text size in points of a 1000 x 500 picture; it follows the square root of the picture's
# size (the smaller of width / 1000 and height / 500), so that small pictures stay readable.
FONT = 12.0
DPI = 100.0
KEY_BAND = 0.17                # fraction of the width on the right that holds the key
LEGEND_ROWS = 16               # classes a legend names at most (the most numerous)
VIZ_HINT = "pip install 'pssd_fast[viz]'"


def _matplotlib():
    """Import what the pictures need from matplotlib, or say how to install it."""
    try:
        from matplotlib import colormaps
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import LinearSegmentedColormap, Normalize, to_rgb, to_rgba
        from matplotlib.figure import Figure
        from matplotlib.image import imsave
        from matplotlib.patches import Patch
    except ImportError as exc:
        raise ImportError(f"pssd_fast.pictures.render needs matplotlib (the optional 'viz' extra): "
                          f"{VIZ_HINT}") from exc
    return SimpleNamespace(colormaps=colormaps, FigureCanvasAgg=FigureCanvasAgg,
                           ScalarMappable=ScalarMappable, Normalize=Normalize, to_rgb=to_rgb,
                           to_rgba=to_rgba, Figure=Figure, imsave=imsave, Patch=Patch,
                           LinearSegmentedColormap=LinearSegmentedColormap)


def _colormap(mpl, cmap):
    """The colour map named ``cmap`` (``"intensity"``: black to light grey), or ``cmap``."""
    if cmap == "intensity":
        return mpl.LinearSegmentedColormap.from_list("intensity",
                                                     [(0.0,) * 3, (INTENSITY_TOP,) * 3])
    return mpl.colormaps.get_cmap("viridis" if cmap is None else cmap)


def _check_size(size):
    if isinstance(size, (str, bytes)) or not hasattr(size, "__len__") or len(size) != 2:
        raise TypeError(f"size must be a pair (width, height) in pixels; got {size!r}")
    width = check_int(size[0], "width", minimum=64, maximum=LARGEST)
    return width, None if size[1] is None else check_int(size[1], "height", minimum=64,
                                                          maximum=LARGEST)


def _as_values(values, n, name="values"):
    """Return ``values`` as ``(n,)`` (a field; NaN allowed: drawn grey) or ``(n, 3)`` (colours)
    float64."""
    arr = np.asarray(values)
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name} must hold real numbers; got dtype {arr.dtype}")
    if arr.shape not in ((n,), (n, 3)):
        raise ValueError(f"{name} must have shape ({n},), one value per point, or ({n}, 3), "
                         f"one colour per point; got shape {arr.shape}")
    return arr if arr.ndim == 2 else arr.astype(np.float64)


def _robust_limits(values, vmin, vmax):
    """``vmin``/``vmax`` where given, else the :data:`ROBUST_PERCENTILES` of the finite
    values."""
    vmin = None if vmin is None else check_float(vmin, "vmin")
    vmax = None if vmax is None else check_float(vmax, "vmax")
    if vmin is not None and vmax is not None and vmax < vmin:
        raise ValueError(f"vmin must not exceed vmax; got vmin={vmin}, vmax={vmax}")
    given = (vmin is not None, vmax is not None)
    if not all(given):
        finite = values[np.isfinite(values)]
        low, high = (np.percentile(finite, ROBUST_PERCENTILES).tolist() if finite.size
                     else (0.0, 1.0))
        # A limit given on one side wins over the percentile on the other.
        if vmin is None:
            vmin = low if vmax is None else min(low, vmax)
        if vmax is None:
            vmax = max(high, vmin)
    if vmax == vmin:  # a constant field: widen on the free sides, so it stays on the scale
        if given == (True, False):
            vmax = vmin + max(abs(vmin), 1.0)
        elif given == (False, True):
            vmin = vmax - max(abs(vmax), 1.0)
        else:  # mid-scale
            vmin, vmax = vmin - 0.5, vmax + 0.5
    return vmin, vmax


def _font(width, height_px):
    """Text size in points (:data:`FONT`)."""
    scale = width / 1000.0 if height_px is None else min(width / 1000.0, height_px / 500.0)
    return FONT * float(np.sqrt(scale))


def _layout(width, height_px, key, title, font):
    """Pixel boxes ``(x0, y0 from the bottom, width, height)`` of the drawing (with and without
    the key's band) and of the key, and the title band's height."""
    margin = max(4, round(0.02 * width))
    title_band = round(2.4 * font * DPI / 72.0) if title else 0
    band = round(KEY_BAND * width)
    height_px = height_px or 0
    keyed = (margin, margin, width - 2 * margin - band, height_px - 2 * margin - title_band)
    drawing = keyed if key else (margin, margin, width - 2 * margin, keyed[3])
    key_box = (width - band + round(0.02 * width), margin + round(0.1 * keyed[3]),
               max(6, round(0.025 * width)), round(0.8 * keyed[3]))
    return drawing, keyed, key_box, title_band


def figure(points, values=None, *, field=None, view=None, up="z", normals=None, cmap=None,
           vmin=None, vmax=None, label=None, units=None, title=None, size=DEFAULT_SIZE,
           point_size=None, background="white", frame=None, missing=None):
    """A point cloud drawn and coloured by a per-point field, as a matplotlib figure.

    :func:`render` draws this figure into an array and a file; take the figure itself to look
    at its parts (``fig.legends``, the colour bar's axes) or to save it in a format of your own
    (``fig.savefig``: an Agg canvas is attached).

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates.
    values : array_like, shape (n,) or (n, 3), optional
        One value per point, coloured through a colour map with a colour bar (NaN drawn grey),
        or by class with a legend when ``field`` is ``"classification"``; or one colour per
        point, drawn as it is (:func:`pssd_fast.pictures.colours.rgb_colours`: 8- or 16-bit
        integers, or floats in ``[0, 1]``) without a key. Without values every point is light
        grey.
    field : str, optional
        ``"classification"`` (``values`` are LiDAR class codes: ASPRS colours and a legend
        naming the classes present, :mod:`pssd_fast.pictures.colours`) or a key of
        :data:`STYLES` (``"feature"``, ``"displacement"``, ``"intensity"``...): its colour map,
        limits and label are the defaults of ``cmap``, ``vmin``, ``vmax`` and ``label``, so
        pictures of a field share one scale. ``values`` must then be in the units of
        :func:`pssd_fast.pictures.fields.field_values`.
    view : (float, float), optional
        ``(elevation, azimuth)`` in degrees (:mod:`pssd_fast.pictures.view`); default
        :func:`pssd_fast.pictures.view.choose_view` of the points: a flat scene obliquely from
        above, its length across the picture, anything else from ``(30, -60)``.
    up : {"x", "y", "z"}, default "z"
        The cloud's axis drawn upwards (:func:`pssd_fast.pictures.view.choose_up` picks one).
    normals : array_like, shape (n, 3), optional
        Normals for Lambert shading under a light at the camera (a headlight), flipped to face
        the viewer so their orientation does not matter. Without them nothing is shaded.
    cmap : str or matplotlib.colors.Colormap, optional
        Colormap for ``values``; default the field's, else "viridis".
    vmin, vmax : float, optional
        Colour limits; default the field's, else the 2nd and 98th percentiles of the finite
        values, so a few outliers do not wash out the rest. Values beyond them take the end
        colours (and the colour bar shows an arrow).
    label : str, optional
        Label of the colour bar; default the field's.
    units : str, optional
        Units of the coordinates (``"m"``, ``"ft"``...), named on the colour bar of a field
        measured in them (``height``, ``displacement``); without them the label says
        "coordinate units".
    title : str, optional
        Title above the picture.
    size : (int, int or None), default (1000, None)
        ``(width, height)`` of the picture in pixels, each from 64 to 8192. A height of None
        follows the cloud: the drawing is as high as the projected cloud at the width's scale
        (between 0.3 of the width for the whole picture and 1.25 of the width for the drawing),
        so a long survey makes a wide picture that it fills.
    point_size : float, optional
        Diameter in pixels of the disc each point may colour; by default 3 mean point spacings
        on screen, capped at a tenth of the picture's short side.
    background : matplotlib colour, default "white"
    frame : array_like, shape (m, 3), optional
        Points whose projection the picture is fitted to; default ``points``. Give several
        clouds one frame (a noisy scan for it and its denoised copy) to make their pictures
        line up: the same scale and place, with a key or without.
    missing : str, optional
        What the points of a scalar field drawn grey (NaN values) are, named in a legend entry
        under the colour bar where there are any ("kept in place (other classes)").

    Returns
    -------
    matplotlib.figure.Figure
        The picture at 100 dots per inch: ``size`` in pixels.

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    TypeError, ValueError
        If an argument has the wrong type, shape or value.

    Notes
    -----
    The projection is orthographic. Its bounding box spans 94% of the drawing's width or
    height, whichever binds (:func:`pssd_fast.pictures.view.fit`), centred. A closing of the
    z-buffer finds the visible surface, so nearer points hide farther ones and a randomly
    sampled surface shows no gaps; each of its pixels shows the nearest of its points on screen
    (a mosaic: the discs' overlap does not blur colours). Points outside the picture are not
    drawn. One million points take a few seconds at most.
    """
    mpl = _matplotlib()
    if field is not None and field != "classification":
        if field not in STYLES:
            raise ValueError(f"field must be classification or one of {', '.join(STYLES)}; "
                             f"got {field!r}")
        style = STYLES[field]
        cmap = style.cmap if cmap is None else cmap
        vmin = style.vmin if vmin is None else vmin
        vmax = style.vmax if vmax is None else vmax
        if label is None:
            label = f"{style.label} ({units or 'coordinate units'})" if style.length \
                else style.label
    pts, _ = as_points(points)
    n = pts.shape[0]
    view = choose_view(pts, up) if view is None else check_view(view)
    camera_basis = basis(view, up)
    width, height_px = _check_size(size)
    vals = None if values is None else _as_values(values, n)
    if field == "classification" and (vals is None or vals.ndim != 1):
        raise ValueError("field 'classification' needs one class code per point")
    nrm = None if normals is None else as_normals(normals, n)
    fitted = pts if frame is None else as_points(frame, "frame")[0]
    if fitted.shape[0] == 0:
        raise ValueError(f"{'points' if frame is None else 'frame'} is empty: a picture needs "
                         "at least one point to fit")
    if point_size is not None:
        point_size = check_float(point_size, "point_size", positive=True)
    background_rgba = np.array(mpl.to_rgba(background))

    # Colours and limits first: bad values are refused before the drawing.
    scalar = vals is not None and vals.ndim == 1 and field != "classification"
    key = scalar or field == "classification"
    classes = None
    if vals is None:
        point_rgb = None
    elif field == "classification":
        point_rgb, classes = class_colours(vals, mpl.colormaps, mpl.to_rgb)
    elif vals.ndim == 2:
        point_rgb = rgb_colours(*vals.T)
    else:
        colormap = _colormap(mpl, cmap)
        norm = mpl.Normalize(*_robust_limits(vals, vmin, vmax), clip=True)
    camera = pts @ camera_basis.T
    ref = camera[:, :2] if frame is None else fitted @ camera_basis[:2].T
    if height_px is None:  # pictures given one frame get one height, as if keyed
        height_px = _free_height(ref, width, key or frame is not None, title)
    font = _font(width, height_px)
    (x0, y0, w, h), keyed, key_box, title_band = _layout(width, height_px, key, title, font)
    if min(w, h) < 1:
        raise ValueError(f"size {width} x {height_px} leaves no room for the drawing beside "
                         "the title and the key; make the picture larger")
    # Pictures given one frame line up whatever their key: they are fitted as if keyed.
    area = (keyed[2], keyed[3]) if frame is not None else (w, h)
    centre, scale = fit(ref, area)
    screen = np.column_stack([0.5 * area[0] + scale * (camera[:, 0] - centre[0]),
                              0.5 * area[1] - scale * (camera[:, 1] - centre[1])])
    if point_size is None:
        reach = splatter.REACH_PER_SPACING * splatter.spacing(pts) * scale
    else:
        reach = 0.5 * point_size
    reach = min(reach, MAX_RADIUS_FRACTION * min(w, h))
    seen = splatter.splat(screen, camera[:, 2], reach,
                          splatter.TOLERANCE_PER_REACH * max(reach, 1.0) / scale, (h, w))

    hit = seen >= 0
    who = seen[hit]
    if vals is None:
        rgb = np.broadcast_to(np.array(PLAIN_GREY), (who.size, 3))
    elif not scalar:
        rgb = point_rgb[who]
    else:
        shown = vals[who]
        rgb = colormap(norm(np.nan_to_num(shown, nan=norm.vmin)))[:, :3]
        rgb[np.isnan(shown)] = NAN_GREY
    if nrm is not None:
        light = AMBIENT + (1.0 - AMBIENT) * np.abs(nrm[who] @ camera_basis[2])
        rgb = rgb * light[:, None]
    image = np.empty((h, w, 4))
    image[:] = background_rgba
    image[hit, :3] = rgb
    image[hit, 3] = 1.0

    fig = mpl.Figure(figsize=(width / DPI, height_px / DPI), dpi=DPI,
                     facecolor=background_rgba)
    mpl.FigureCanvasAgg(fig)
    # figimage places the buffer pixel for pixel (no resampling); yo counts from the bottom.
    fig.figimage(image, xo=x0, yo=y0, origin="upper")
    if scalar:
        if missing is not None and np.isnan(vals).any():
            key_box = _missing_entry(fig, mpl, missing, key_box, (width, height_px), font)
        _colour_bar(fig, mpl, vals, colormap, norm, key_box, (width, height_px), label, font)
    elif classes is not None:
        _legend(fig, mpl, classes, key_box, (width, height_px), font)
    if title:
        fig.text(0.5, 1.0 - 0.5 * title_band / height_px, title, ha="center", va="center",
                 fontsize=1.2 * font)
    return fig


def _free_height(ref, width, key, title):
    """Height of a picture ``width`` wide whose drawing holds the projected points ``ref`` at
    the width's scale (:data:`TALLEST`, :data:`FLATTEST`)."""
    _, keyed, _, title_band = _layout(width, None, key, title, _font(width, None))
    drawing_width = keyed[2] if key else width - 2 * keyed[0]
    span = np.ptp(ref, axis=0)
    ratio = span[1] / span[0] if span[0] > 0 else TALLEST
    drawing = min(TALLEST, ratio) * drawing_width
    return max(64, round(FLATTEST * width), round(drawing + 2 * keyed[1] + title_band))


def _colour_bar(fig, mpl, vals, colormap, norm, box, size, label, font):
    """The colour bar of a scalar field in ``box`` (pixels), arrows where values go beyond
    the limits."""
    finite = vals[np.isfinite(vals)]
    below = finite.size > 0 and finite.min() < norm.vmin
    above = finite.size > 0 and finite.max() > norm.vmax
    extend = ("both" if above else "min") if below else ("max" if above else "neither")
    (bx, by, bw, bh), (width, height_px) = box, size
    cax = fig.add_axes((bx / width, by / height_px, bw / width, bh / height_px))
    bar = fig.colorbar(mpl.ScalarMappable(norm=norm, cmap=colormap), cax=cax, extend=extend)
    bar.ax.tick_params(labelsize=0.85 * font)
    if label:
        bar.set_label(label, fontsize=font)


def _missing_entry(fig, mpl, text, box, size, font):
    """A legend entry naming the grey points (``text``) at the foot of the key's ``box``;
    returns the box left above it for the colour bar."""
    (bx, by, bw, bh), (width, height_px) = box, size
    entry = min(0.25 * bh, 3.0 * font * DPI / 72.0)
    fig.legend([mpl.Patch(facecolor=NAN_GREY, edgecolor="none")], [text], loc="lower left",
               bbox_to_anchor=(bx / width - 0.01, by / height_px), frameon=False,
               fontsize=0.85 * font, handlelength=1.0, borderaxespad=0.0)
    return bx, by + entry, bw, bh - entry


def _legend(fig, mpl, classes, box, size, font):
    """A legend naming the classes present, by code, in the key's band; the most numerous
    :data:`LEGEND_ROWS` when there are more, with a row that counts the others."""
    shown = classes
    if len(classes) > LEGEND_ROWS:
        most = sorted(classes, key=lambda c: -c[1])[:LEGEND_ROWS - 1]
        shown = sorted(most)
    handles = [mpl.Patch(facecolor=colour, edgecolor="none") for _, _, colour in shown]
    labels = [class_name(code) for code, _, _ in shown]
    if len(shown) < len(classes):
        handles.append(mpl.Patch(facecolor="none", edgecolor="none"))
        labels.append(f"+{len(classes) - len(shown)} other classes")
    (bx, by, _, bh), (width, height_px) = box, size
    # Rows of about 1.9 font heights (entry and spacing), the title one more: shrink to fit.
    rows = len(labels) + 1
    font = min(font, bh * 72.0 / DPI / (1.9 * rows))
    fig.legend(handles, labels, loc="upper left", frameon=False, fontsize=font,
               title="classification", title_fontsize=font, alignment="left",
               bbox_to_anchor=((bx - round(0.01 * width)) / width, (by + bh) / height_px),
               handlelength=1.2, borderaxespad=0.0, borderpad=0.0)


def render(points, values=None, path=None, **options):
    """Draw a point cloud coloured by a per-point field; optionally write it to a file.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates.
    values : array_like, shape (n,) or (n, 3), optional
        One value or one colour per point (:func:`figure`).
    path : str or os.PathLike, optional
        Picture to write, in the format of its extension (:func:`image_format`), atomically:
        a temporary file in the same folder, then renamed.
    **options
        ``field``, ``view``, ``up``, ``normals``, ``cmap``, ``vmin``, ``vmax``, ``label``,
        ``units``, ``title``, ``size``, ``point_size``, ``background`` and ``frame``, as for
        :func:`figure`.

    Returns
    -------
    (height, width, 4) uint8
        The RGBA picture, as written to ``path``.

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    TypeError, ValueError
        If an argument has the wrong type, shape or value; an unknown picture format is refused
        before any drawing.

    Examples
    --------
    >>> import numpy as np
    >>> from pssd_fast import datasets, pictures
    >>> cloud = datasets.sphere(2000, noise=0.0, seed=1)
    >>> image = pictures.render(cloud.points, cloud.points[:, 2], field="height",
    ...                         normals=cloud.normals, size=(320, 240))
    >>> image.shape, image.dtype
    ((240, 320, 4), dtype('uint8'))
    """
    mpl = _matplotlib()
    image_type = None if path is None else image_format(path)
    fig = figure(points, values, **options)
    fig.canvas.draw()
    picture = np.array(fig.canvas.buffer_rgba(), dtype=np.uint8)
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
               units=None, size=DEFAULT_SIZE):
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
    units : str, optional
        Units of the coordinates, for the displacement's colour bar (:func:`figure`).
    size : (int, int or None), default (1000, None)
        ``(width, height)`` of each picture in pixels; a height of None follows the input's
        projection, the same for all six.

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
    Every picture is fitted to the input (``frame``), so all six line up, and uses the field's
    :data:`STYLES`, as ``pssd render`` does: the curvature pictures of the input and the
    output (:func:`pssd_fast.pictures.fields.curvature` of each) share one scale, and each picture
    equals what ``pssd render`` draws for the same field of the same points.
    """
    from .fields import curvature
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
    common = {"view": view, "up": up, "size": size, "frame": noisy_pts, "units": units}
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
         fields["displacement"], "displacement",
         "Denoised: displacement"),
    ]
    paths = []
    for name, pts, nrm, vals, field, title in pictures:
        render(pts, vals, folder / name, field=field, normals=nrm, title=title, **common)
        paths.append(folder / name)
    return paths
