"""Colours of the pictures: one style per scalar field, the ASPRS classes, and RGB as stored.

Scalar fields go through a colour map with a colour bar (:data:`STYLES`); LiDAR classes get a
categorical palette with a legend (:func:`class_colours`); a file's own colours are drawn as they
are (:func:`rgb_colours`).
"""
from typing import NamedTuple, Optional

import numpy as np

__all__ = ["ASPRS_CLASSES", "CLASS_COLOURS", "ROBUST_PERCENTILES", "STYLES", "Style",
           "class_colours", "class_name", "rgb_colours"]


class Style(NamedTuple):
    """Colour map, colour limits (None: the :data:`ROBUST_PERCENTILES` of the values),
    colour-bar label, and whether the field is a length (its label then names the units)."""

    cmap: str
    vmin: Optional[float]
    vmax: Optional[float]
    label: str
    length: bool = False


#: Percentiles of the values that bound a colour scale where the style fixes no limit, so that
#: a few outliers (a bird above a survey, a stray return) do not wash out the rest.
ROBUST_PERCENTILES = (2.0, 98.0)
#: Style of each field, in the units of :func:`pssd_fast.pictures.fields.field_values`. Feature
#: intensity and likelihood lie in [0, 1] by definition. Curvature times the diagonal: +-50
#: shows the noise of a raw scan (median |H| d is 28 on the CAD part at 0.25% noise, 8 on
#: Igea's vertices) and how much denoising removes (4 on the denoised part) while sharp edges
#: (150 and more) saturate. Displacement, in the units of the coordinates: from 0 to its 98th
#: percentile (a fixed fraction of the diagonal made a survey's centimetres one dark colour).
#: Height and intensity: between their 2nd and 98th percentiles; intensity as a grey ramp, as
#: LiDAR viewers draw it (ending at light grey, which stays visible on a white background).
STYLES = {
    "feature": Style("YlOrRd", 0.0, 1.0, "feature intensity"),
    "likelihood": Style("viridis", 0.0, 1.0, "sampling likelihood"),
    "curvature": Style("RdBu_r", -50.0, 50.0, "mean curvature x diagonal"),
    "displacement": Style("plasma", 0.0, None, "displacement", length=True),
    "height": Style("cividis", None, None, "height", length=True),
    "intensity": Style("intensity", None, None, "intensity"),
}
#: The grey ramp of ``intensity``: black to this grey.
INTENSITY_TOP = 0.92

#: Names of the ASPRS standard classes (LAS 1.4 R15, table 17; 8 and 12 as LAS 1.0-1.3 named
#: them, reserved since).
ASPRS_CLASSES = {
    0: "Never classified", 1: "Unclassified", 2: "Ground", 3: "Low vegetation",
    4: "Medium vegetation", 5: "High vegetation", 6: "Building", 7: "Low point (noise)",
    8: "Model key-point", 9: "Water", 10: "Rail", 11: "Road surface", 12: "Overlap",
    13: "Wire guard", 14: "Wire conductor", 15: "Transmission tower", 16: "Wire connector",
    17: "Bridge deck", 18: "High noise", 19: "Overhead structure", 20: "Ignored ground",
    21: "Snow", 22: "Temporal exclusion",
}
#: Colour of each ASPRS class, as LiDAR viewers conventionally draw them: greys for the
#: unclassified, earth for ground, greens for vegetation, red buildings, blue water, magenta
#: and pink noise. Other codes take colours of matplotlib's ``tab20`` by code.
CLASS_COLOURS = {
    0: "#c8c8c8", 1: "#969696", 2: "#a6761d", 3: "#b8e186", 4: "#5aae61", 5: "#1b7837",
    6: "#e31a1c", 7: "#ff00ff", 8: "#fdbf6f", 9: "#1f78b4", 10: "#6a3d9a", 11: "#404040",
    12: "#ffd92f", 13: "#ff7f00", 14: "#ffff33", 15: "#b15928", 16: "#cab2d6",
    17: "#984ea3", 18: "#f781bf", 19: "#8dd3c7", 20: "#d9b38c", 21: "#a6cee3",
    22: "#bdbdbd",
}


def class_name(code):
    """The legend's name of class ``code``: ``"2 Ground"``, ``"40 (reserved)"``,
    ``"70 (user-defined)"``."""
    if code in ASPRS_CLASSES:
        return f"{code} {ASPRS_CLASSES[code]}"
    return f"{code} (reserved)" if code < 64 else f"{code} (user-defined)"


def class_colours(codes, colormaps, to_rgb):
    """Colour of each point by its class, and the classes present.

    Parameters
    ----------
    codes : (n,) array_like of int
        Class of each point.
    colormaps, to_rgb : matplotlib's registry of colour maps and its ``to_rgb``.

    Returns
    -------
    rgb : (n, 3) float64
        Colours in ``[0, 1]``.
    present : list of (int, int, (float, float, float))
        ``(code, points, colour)`` of each class present, by code.

    Raises
    ------
    ValueError
        If ``codes`` are not whole numbers from 0 to 255, as LAS stores them.
    """
    arr = np.asarray(codes)
    if arr.dtype.kind not in "iub" and not (arr.dtype.kind == "f"
                                           and np.array_equal(arr, np.round(arr))):
        raise ValueError(f"classification must hold whole class numbers; got dtype {arr.dtype}")
    if arr.size and (arr.min() < 0 or arr.max() > 255):
        raise ValueError(f"classification must lie in 0-255 as LAS classes do; got "
                         f"{arr.min():g} to {arr.max():g}")
    arr = arr.astype(np.intp)
    counts = np.bincount(arr, minlength=256)
    others = colormaps["tab20"]
    table = np.array([to_rgb(CLASS_COLOURS[c]) if c in CLASS_COLOURS else others(c % 20)[:3]
                      for c in range(256)])
    present = [(int(c), int(counts[c]), tuple(table[c])) for c in np.flatnonzero(counts)]
    return table[arr], present


def rgb_colours(red, green, blue):
    """A file's own colours as ``(n, 3)`` floats in ``[0, 1]``.

    Parameters
    ----------
    red, green, blue : (n,) array_like
        Values of 8 bits (at most 255 everywhere) or 16 bits (LAS stores 16; files with 8-bit
        values in 16-bit fields are read as 8-bit, as viewers do); floats in ``[0, 1]`` are taken
        as they are, larger ones as 8 or 16 bits alike.

    Returns
    -------
    (n, 3) float64

    Raises
    ------
    ValueError
        For values that are not numbers, negative, not finite or above 65535.
    """
    rgb = np.column_stack([np.asarray(c) for c in (red, green, blue)])
    kind = rgb.dtype.kind
    if kind not in "fiub":
        raise ValueError(f"red, green and blue must hold numbers; got dtype {rgb.dtype}")
    rgb = rgb.astype(np.float64)
    if rgb.size and (not np.isfinite(rgb).all() or rgb.min() < 0 or rgb.max() > 65535):
        raise ValueError(f"red, green and blue must lie in 0-1, 0-255 or 0-65535; got "
                         f"{rgb.min():g} to {rgb.max():g}")
    high = rgb.max() if rgb.size else 0.0
    top = 1.0 if kind == "f" and high <= 1.0 else 255.0 if high <= 255.0 else 65535.0
    return rgb / top
