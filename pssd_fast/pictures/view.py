"""Where a picture is seen from and what it holds: up axes, views and framing.

Views are ``(elevation, azimuth)`` in degrees about the cloud's *up* axis (``"z"`` unless
``up`` says otherwise). With ``z`` up: ``(0, 0)`` looks along ``+y`` (``x`` to the right, ``z``
up), a positive azimuth turns the camera counter-clockwise about ``z`` seen from above
(``(0, 90)`` looks along ``-x``), and a positive elevation raises it above the ``xy`` plane.
Another up axis is first turned to ``z`` by a rotation: ``"y"`` by +90 degrees about ``x``
(``y`` to ``z``, ``z`` to ``-y``: a model facing ``+z``, as y-up models do, faces the default
view), ``"x"`` by the cyclic exchange that makes ``x`` the new ``z`` (and ``y`` the new
``x``). :func:`choose_up` picks the up axis from the data, :func:`choose_view` the view.

The picture holds the projection of the cloud, not a sphere about it: :func:`fit` scales the
projected bounding box to the drawing area, so a wide scene fills a wide picture.
"""
import numpy as np

from .._validation import as_points, check_float

__all__ = ["DEFAULT_VIEW", "FLAT_EXTENT", "SCENE_ELEVATION", "TURN_SLACK", "UP_AXES", "basis",
           "choose_up", "choose_view", "fit", "height"]

#: Axes that can point up in a picture.
UP_AXES = ("x", "y", "z")
# Rotation of each up axis to z (rows: the new x, y, z in the cloud's coordinates).
_TO_Z_UP = {"z": np.eye(3),
            "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
            "x": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])}
#: A cloud whose least extent is under this fraction of its largest is flat (a terrain, a
#: survey, a facade, a plate): :func:`choose_up` sees it from the side of its least extent and
#: :func:`choose_view` draws it as a scene.
FLAT_EXTENT = 1.0 / 3.0
#: ``(elevation, azimuth)`` in degrees: from above, in front and to the left.
DEFAULT_VIEW = (30.0, -60.0)
#: Elevation in degrees of the view of a flat scene (:func:`choose_view`): steep enough that
#: the ground reads as a map and nothing tall hides much of it, low enough that trees,
#: buildings and relief show their sides.
SCENE_ELEVATION = 50.0
# Points of the turn of choose_view (every n-th): their extents in 180 directions take 29 MB.
TURN_SAMPLE = 20_000
#: Bounding rectangles within this fraction of the smallest fill a picture alike: among their
#: turns :func:`choose_view` takes the one nearest to north-up.
TURN_SLACK = 0.02
#: Fraction of the drawing area's width or height (whichever binds) that the projected
#: bounding box spans: the rest is margin, a little more than the half spacing by which the
#: drawn surface reaches beyond its outermost points.
FILL = 0.94


def check_view(view):
    """Return ``view`` as finite ``(elevation, azimuth)`` floats."""
    if isinstance(view, (str, bytes)) or not hasattr(view, "__len__") or len(view) != 2:
        raise TypeError(f"view must be a pair (elevation, azimuth) in degrees; got {view!r}")
    return (check_float(view[0], "view elevation"), check_float(view[1], "view azimuth"))


def check_up(up):
    """Return ``up``, one of :data:`UP_AXES`."""
    if up not in UP_AXES:
        raise ValueError(f"up must be one of {', '.join(UP_AXES)}; got {up!r}")
    return up


def basis(view, up="z"):
    """Rows ``right, up, towards the viewer`` of the camera for ``(elevation, azimuth)`` about
    the ``up`` axis, in the cloud's coordinates."""
    elev, azim = np.radians(check_view(view))
    ce, se, ca, sa = np.cos(elev), np.sin(elev), np.cos(azim), np.sin(azim)
    right = [ca, sa, 0.0]
    screen_up = [-se * sa, se * ca, ce]
    eye = [ce * sa, -ce * ca, se]
    return np.array([right, screen_up, eye]) @ _TO_Z_UP[check_up(up)]


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
        :data:`FLAT_EXTENT` of the largest: a terrain, a facade, a plate), the axis of its least
        extent, so that it is seen from above; else ``"y"``, the convention of scanned models and
        mesh formats (the Stanford and Cyberware scans, OBJ and PLY tools), under which Igea,
        the bunny and the dragon stand upright.
    """
    if georeferenced:
        return "z"
    pts, _ = as_points(points)
    extent = pts.max(axis=0) - pts.min(axis=0)
    least = int(np.argmin(extent))
    return UP_AXES[least] if extent[least] < FLAT_EXTENT * extent.max() else "y"


def choose_view(points, up="z"):
    """The view of a picture of ``points`` when none is given.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        Coordinates.
    up : {"x", "y", "z"}, default "z"
        The cloud's up axis.

    Returns
    -------
    (float, float)
        ``(elevation, azimuth)`` in degrees. A flat scene (extent along ``up`` under
        :data:`FLAT_EXTENT` of its length: a survey, a terrain, a floor) is seen from
        :data:`SCENE_ELEVATION`, turned so that its smallest bounding rectangle seen from above
        lies with its long side across the picture: the scene then fills a wide picture. Of the
        turns whose rectangle is within :data:`TURN_SLACK` of the smallest, the one nearest to
        azimuth 0 (``+y``, north for georeferenced data, pointing away), in ``(-90, 90]``.
        Anything else is seen from :data:`DEFAULT_VIEW`.
    """
    pts, _ = as_points(points)
    if pts.shape[0] < 2:
        return DEFAULT_VIEW
    level = pts @ _TO_Z_UP[check_up(up)].T
    ground = level[::max(1, pts.shape[0] // TURN_SAMPLE), :2]
    ground = ground - ground.mean(axis=0)
    turns = np.arange(0.0, 180.0, 1.0)
    across = np.radians(turns)
    extent = np.ptp(ground @ np.array([np.cos(across), np.sin(across)]), axis=0)
    # The extent across the picture at each turn and, 90 degrees on, the extent into it.
    deep = np.roll(extent, -90)
    length = np.maximum(extent, deep)
    if not np.ptp(level[:, 2]) < FLAT_EXTENT * length.max():
        return DEFAULT_VIEW
    area = extent * deep
    # Long side across: a turn whose own extent is the short one is taken 90 degrees on.
    azimuth = np.where(extent >= deep, turns, turns + 90.0)
    azimuth = (azimuth + 90.0) % 180.0 - 90.0  # in [-90, 90)
    azimuth[azimuth == -90.0] = 90.0
    best = np.flatnonzero(area <= (1.0 + TURN_SLACK) * area.min())
    return (SCENE_ELEVATION, float(azimuth[best[np.argmin(np.abs(azimuth[best]))]]))


def height(points, up="z"):
    """Coordinate of each point along the up axis, for the ``"height"`` colouring.

    Parameters
    ----------
    points, up
        As in :func:`choose_view`.

    Returns
    -------
    (n,) float64
        The ``up`` coordinate (elevation, for a terrain): whatever the view, larger values lie
        higher.
    """
    pts, _ = as_points(points)
    return pts[:, UP_AXES.index(check_up(up))].copy()


def fit(screen_points, area):
    """Centre and scale that fit points seen on screen to a drawing area.

    Parameters
    ----------
    screen_points : (m, 2) float64
        The points to fit (the cloud, or the frame given for several pictures), as camera
        ``(right, up)`` coordinates.
    area : (float, float)
        ``(width, height)`` of the drawing area in pixels.

    Returns
    -------
    centre : (2,) float64
        Camera coordinates drawn at the middle of the area.
    scale : float
        Pixels per unit of length: the projected bounding box spans :data:`FILL` of the area's
        width or height, whichever binds.
    """
    low, high = screen_points.min(axis=0), screen_points.max(axis=0)
    limits = [FILL * a / s for a, s in zip(area, high - low, strict=True) if s > 0]
    scale = min(limits) if limits else 0.5 * FILL * min(area)  # one location: any scale fits
    return 0.5 * (low + high), scale
