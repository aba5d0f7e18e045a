"""The splatter behind the pictures: which point each pixel shows, in numpy.

An orthographic projection is drawn with a z-buffer and one disc per point whose size follows the
cloud's spacing on screen, so that a sampled surface looks closed (:func:`splat`). Colours,
layout and files are :mod:`.draw`'s business.
"""
import numpy as np

__all__ = ["REACH_PER_SPACING", "TOLERANCE_PER_REACH", "disc", "disc_filter", "spacing",
           "splat"]

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


def spacing(points):
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


def disc(radius):
    """Integer pixel offsets ``(dy, dx)`` of a disc of ``radius`` pixels (one pixel if < 1)."""
    reach = int(np.floor(radius))
    dy, dx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    inside = dy**2 + dx**2 <= radius**2
    return dy[inside], dx[inside]


def splat(screen, depth, reach, tolerance, shape):
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
    surface = disc_filter(disc_filter(nearest, close, np.maximum), shrink, np.minimum)
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
    dy, dx = disc(reach)
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


def disc_filter(image, radius, reduce):
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
