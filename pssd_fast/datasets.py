"""Seeded synthetic point clouds with exact ground truth, for tests and benchmarks.

Every generator samples a known surface uniformly by area, adds isotropic Gaussian noise whose
standard deviation is a fraction ``noise`` of the clean shape's bounding-box diagonal, and
returns a :class:`SyntheticCloud` holding the noisy points together with the exact clean
samples, their true outward normals, their distance to the shape's sharp edges, and an exact
analytic distance-to-surface function for scoring a denoiser's output.

All randomness comes from ``np.random.default_rng(seed)``: the same arguments give
bit-identical arrays. The clean samples are drawn before the noise, so changing only ``noise``
keeps ``clean``, ``normals`` and ``edge_distance`` unchanged.
"""
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ._validation import check_int, seeded_rng

__all__ = [
    "GENERATORS",
    "SyntheticCloud",
    "cad_part",
    "cube",
    "cylinder",
    "make",
    "plane",
    "sphere",
]


@dataclass(frozen=True, eq=False, repr=False)
class SyntheticCloud:
    """A noisy point cloud sampled from a known surface, with its exact ground truth.

    Attributes
    ----------
    name : str
        Generator name (a key of :data:`GENERATORS`).
    points : (n, 3) float64
        Noisy points: ``clean`` plus isotropic Gaussian noise of std ``noise_sigma``.
    clean : (n, 3) float64
        The exact surface samples the noise was added to.
    normals : (n, 3) float64
        Unit outward normals of the true surface at ``clean`` (of the face or patch each sample
        was drawn on).
    noise_sigma : float
        Absolute standard deviation of the noise, per coordinate.
    diagonal : float
        Bounding-box diagonal of the clean shape.
    edge_distance : (n,) float64
        Distance from each clean point to the nearest sharp edge curve of the shape (dihedral
        angle above 30 degrees); ``inf`` for shapes without sharp edges.

    Notes
    -----
    Build instances with the generators of this module; the private field
    ``_unsigned_distance`` holds the shape's analytic distance function behind
    :meth:`surface_distance`. The arrays are read-only so that a cloud can be shared between
    tests and benchmarks without one of them corrupting it. Equality is identity
    (``eq=False``): comparing clouds field by field would mean comparing arrays elementwise.
    """

    name: str
    points: np.ndarray
    clean: np.ndarray
    normals: np.ndarray
    noise_sigma: float
    diagonal: float
    edge_distance: np.ndarray
    _unsigned_distance: Callable[[np.ndarray], np.ndarray] = field(repr=False)

    def __post_init__(self):
        for array in (self.points, self.clean, self.normals, self.edge_distance):
            array.setflags(write=False)

    def __repr__(self):
        return (f"SyntheticCloud(name={self.name!r}, n={len(self.points)}, "
                f"noise_sigma={self.noise_sigma:.6g}, diagonal={self.diagonal:.6g})")

    def surface_distance(self, points):
        """Exact unsigned Euclidean distance from query points to the true surface.

        Parameters
        ----------
        points : (m, 3) array_like of float
            Query points, in the same coordinates as :attr:`points`.

        Returns
        -------
        (m,) float64
            Distance of each query point to the closed surface (to the square, boundary
            included, for ``plane``).

        Raises
        ------
        ValueError
            If ``points`` does not have shape (m, 3) or is not finite.

        Notes
        -----
        Computed analytically from the shape's exact signed distance function, not from the
        samples, so it is exact up to floating-point rounding everywhere, including near
        concave corners.
        """
        query = np.asarray(points, dtype=np.float64)
        if query.ndim != 2 or query.shape[1] != 3:
            raise ValueError(f"points must have shape (m, 3), got {query.shape}")
        if not np.isfinite(query).all():
            raise ValueError("points contains non-finite values")
        return self._unsigned_distance(query)

    def errors(self, result):
        """Errors of a denoising ``result`` (a :class:`pssd_fast.DenoiseResult` of
        :attr:`points`) in the paper's unit, 1e-4 of the diagonal.

        Returns
        -------
        before, after, moved : (n,) float64
            Distance to the true surface before and after, and the displacement.
        edge : (n,) bool
            Points within 1% of the diagonal of a sharp edge.
        """
        unit = 1e-4 * self.diagonal
        return (self.surface_distance(self.points) / unit,
                self.surface_distance(result.points) / unit, result.displacement / unit,
                self.edge_distance < 0.01 * self.diagonal)


# --------------------------------------------------------------------------------------------
# argument checks and shared assembly


def _check_real(value, name, positive):
    """``value`` as a finite float, > 0 if ``positive`` else >= 0, naming ``name`` on error."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if not np.isfinite(value) or value < 0 or (positive and value == 0):
        raise ValueError(f"{name} must be finite and {'> 0' if positive else '>= 0'}, "
                         f"got {value}")
    return value


def _start(n_points, noise, seed, areas):
    """Check the common arguments; return the rng, ``noise`` as a float and per-patch counts.

    The counts are one multinomial draw of ``n_points`` over patches weighted by ``areas``.
    """
    n_points = check_int(n_points, "n_points", minimum=1)
    noise = _check_real(noise, "noise", positive=False)
    rng = seeded_rng(seed)
    areas = np.asarray(areas, dtype=np.float64)
    return rng, noise, rng.multinomial(n_points, areas / areas.sum())


def _finish(name, rng, noise, diagonal, clean, normals, edge_distance, distance):
    """Shuffle the patch-ordered samples, add the noise and wrap everything up."""
    # Patches are generated one after another; shuffling keeps the point order from encoding
    # which patch a point came from.
    order = rng.permutation(len(clean))
    clean = clean[order]
    sigma = float(noise * diagonal)
    points = clean + rng.normal(0.0, sigma, size=clean.shape)
    return SyntheticCloud(name=name, points=points, clean=clean, normals=normals[order],
                          noise_sigma=sigma, diagonal=float(diagonal),
                          edge_distance=edge_distance[order], _unsigned_distance=distance)


def _extrusion_distance(d2, z, half_height):
    """Unsigned distance to an extruded solid from its 2-D signed distance ``d2`` and ``z``.

    The standard exact extrusion SDF: with ``w = (d2, |z| - h)``,
    ``sdf = min(max(w0, w1), 0) + |max(w, 0)|``.
    """
    w1 = np.abs(z) - half_height
    return np.abs(np.minimum(np.maximum(d2, w1), 0.0)
                  + np.hypot(np.maximum(d2, 0.0), np.maximum(w1, 0.0)))


# --------------------------------------------------------------------------------------------
# generators


def plane(n_points=10000, noise=0.005, seed=0):
    """The unit square ``[0, 1]^2`` at ``z = 0``, an open surface without sharp edges.

    Parameters
    ----------
    n_points : int, optional
        Number of points, at least 1.
    noise : float, optional
        Noise std as a fraction of the bounding-box diagonal (``sqrt(2)``); may be 0.
    seed : int, optional
        Non-negative seed of ``np.random.default_rng``.

    Returns
    -------
    SyntheticCloud
        Normals are all ``+z``; ``edge_distance`` is ``inf`` (the boundary is not a sharp
        edge).

    Raises
    ------
    TypeError
        If ``n_points`` or ``seed`` is not an integer or ``noise`` is not a real number.
    ValueError
        If ``n_points < 1``, ``noise`` is negative or not finite, or ``seed < 0``.

    Notes
    -----
    ``surface_distance`` is the exact distance to the square, boundary included:
    ``sqrt(dx^2 + dy^2 + z^2)`` with ``dx = max(-x, 0, x - 1)`` and likewise ``dy``.
    """
    rng, noise, (n,) = _start(n_points, noise, seed, [1.0])
    clean = np.column_stack([rng.random((n, 2)), np.zeros(n)])
    normals = np.broadcast_to([0.0, 0.0, 1.0], (n, 3))

    def distance(q):
        outside = np.maximum(np.maximum(-q[:, :2], q[:, :2] - 1.0), 0.0)
        return np.sqrt(outside[:, 0] ** 2 + outside[:, 1] ** 2 + q[:, 2] ** 2)

    return _finish("plane", rng, noise, np.sqrt(2.0), clean, normals, np.full(n, np.inf),
                   distance)


def sphere(n_points=20000, noise=0.005, seed=0, radius=0.5):
    """A sphere centred at the origin, a smooth closed surface.

    Parameters
    ----------
    n_points, noise, seed
        As in :func:`plane`; the bounding-box diagonal is ``2 sqrt(3) radius``.
    radius : float, optional
        Sphere radius, > 0.

    Returns
    -------
    SyntheticCloud
        Normals point radially outwards; ``edge_distance`` is ``inf``.

    Raises
    ------
    TypeError, ValueError
        As in :func:`plane`; ValueError also where ``radius`` is not positive and finite.

    Notes
    -----
    Directions are normalised standard Gaussian vectors, which are uniform on the sphere.
    ``surface_distance`` is ``| |p| - radius |``.
    """
    radius = _check_real(radius, "radius", positive=True)
    rng, noise, (n,) = _start(n_points, noise, seed, [1.0])
    normals = rng.standard_normal((n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)

    def distance(q):
        return np.abs(np.linalg.norm(q, axis=1) - radius)

    return _finish("sphere", rng, noise, 2.0 * np.sqrt(3.0) * radius, radius * normals,
                   normals, np.full(n, np.inf), distance)


def cylinder(n_points=40000, noise=0.005, seed=0, radius=0.3, height=0.8):
    """A closed cylinder along ``z`` with flat caps, centred at the origin.

    Parameters
    ----------
    n_points, noise, seed
        As in :func:`plane`; the bounding-box diagonal is ``sqrt(8 radius^2 + height^2)``.
    radius : float, optional
        Radius, > 0.
    height : float, optional
        Height (``z`` spans ``[-height/2, height/2]``), > 0.

    Returns
    -------
    SyntheticCloud
        The sharp edges are the two rims (90 degrees): ``edge_distance`` is
        ``height/2 - |z|`` on the side wall and ``radius - r`` on a cap.

    Raises
    ------
    TypeError, ValueError
        As in :func:`plane`; ValueError also where ``radius`` or ``height`` is not positive
        and finite.

    Notes
    -----
    Counts are split between side wall and caps by a multinomial draw over their areas
    (``2 pi r h`` and ``pi r^2`` each); cap points use ``r = radius sqrt(u)``, which is uniform
    by area on a disk. ``surface_distance`` is the exact capped-cylinder SDF (the extrusion of
    a disk), in absolute value.
    """
    radius = _check_real(radius, "radius", positive=True)
    height = _check_real(height, "height", positive=True)
    half = 0.5 * height
    rng, noise, (n_side, n_top, n_bottom) = _start(
        n_points, noise, seed, [2.0 * np.pi * radius * height, np.pi * radius**2,
                                np.pi * radius**2])
    n_caps = n_top + n_bottom

    theta = rng.uniform(0.0, 2.0 * np.pi, n_side)
    z = rng.uniform(-half, half, n_side)
    side = np.column_stack([radius * np.cos(theta), radius * np.sin(theta), z])
    side_normals = np.column_stack([np.cos(theta), np.sin(theta), np.zeros(n_side)])

    r = radius * np.sqrt(rng.random(n_caps))
    phi = rng.uniform(0.0, 2.0 * np.pi, n_caps)
    up = np.r_[np.ones(n_top), -np.ones(n_bottom)]
    caps = np.column_stack([r * np.cos(phi), r * np.sin(phi), half * up])
    cap_normals = np.column_stack([np.zeros(n_caps), np.zeros(n_caps), up])

    def distance(q):
        return _extrusion_distance(np.hypot(q[:, 0], q[:, 1]) - radius, q[:, 2], half)

    return _finish("cylinder", rng, noise, np.sqrt(8.0 * radius**2 + height**2),
                   np.concatenate([side, caps]), np.concatenate([side_normals, cap_normals]),
                   np.concatenate([half - np.abs(z), radius - r]), distance)


def cube(n_points=60000, noise=0.005, seed=0, side=1.0):
    """An axis-aligned cube centred at the origin.

    Parameters
    ----------
    n_points, noise, seed
        As in :func:`plane`; the bounding-box diagonal is ``sqrt(3) side``.
    side : float, optional
        Edge length, > 0.

    Returns
    -------
    SyntheticCloud
        The sharp edges are the 12 cube edges: ``edge_distance`` of a point on a face is
        ``side/2`` minus the larger absolute value of its two in-face coordinates.

    Raises
    ------
    TypeError, ValueError
        As in :func:`plane`; ValueError also where ``side`` is not positive and finite.

    Notes
    -----
    Face counts are one multinomial draw with equal probabilities. ``surface_distance`` is
    the exact box SDF ``|max(q, 0)| + min(max_i q_i, 0)`` with ``q = |p| - side/2``, in
    absolute value.
    """
    side = _check_real(side, "side", positive=True)
    half = 0.5 * side
    rng, noise, counts = _start(n_points, noise, seed, np.ones(6))
    face = np.repeat(np.arange(6), counts)
    axis = face // 2
    sign = np.where(face % 2 == 0, 1.0, -1.0)
    rows = np.arange(len(face))

    clean = rng.uniform(-half, half, (len(face), 3))
    clean[rows, axis] = sign * half
    normals = np.zeros_like(clean)
    normals[rows, axis] = sign
    # The nearest edge borders the point's own face: the in-face coordinate closest to +-half.
    in_face = np.abs(clean)
    in_face[rows, axis] = 0.0
    edge_distance = half - in_face.max(axis=1)

    def distance(q):
        over = np.abs(q) - half
        return np.abs(np.linalg.norm(np.maximum(over, 0.0), axis=1)
                      + np.minimum(over.max(axis=1), 0.0))

    return _finish("cube", rng, noise, np.sqrt(3.0) * side, clean, normals, edge_distance,
                   distance)


# --------------------------------------------------------------------------------------------
# the CAD-like part: an extruded 2-D profile with a notch and a rounded end

# Straight part of the profile boundary, counter-clockwise: bottom, right, the two notch steps,
# top. The boundary closes with a half circle from (-1, 0.5) round to (-1, -0.5).
_CAD_CORNERS = np.array([[-1.0, -0.5], [1.0, -0.5], [1.0, 0.0], [0.4, 0.0], [0.4, 0.5],
                         [-1.0, 0.5]])
_CAD_SEG_A = _CAD_CORNERS[:-1]
_CAD_SEG_B = _CAD_CORNERS[1:]
_CAD_ARC_CENTRE = np.array([-1.0, 0.0])
_CAD_ARC_RADIUS = 0.5
_CAD_HALF_HEIGHT = 0.3
# Vertical sharp edges: the corners where two straight sides meet (the arc joins the top and
# bottom lines tangentially, so its ends are smooth).
_CAD_VERTICAL_EDGES = _CAD_CORNERS[1:5]
_CAD_BOX_LO = np.array([-1.5, -0.5, -_CAD_HALF_HEIGHT])
_CAD_BOX_HI = np.array([1.0, 0.5, _CAD_HALF_HEIGHT])
_CAD_CENTRE = 0.5 * (_CAD_BOX_LO + _CAD_BOX_HI)
_CAD_SCALE = 1.0 / np.linalg.norm(_CAD_BOX_HI - _CAD_BOX_LO)


def _cad_inside(x, y):
    """Whether 2-D points lie in the profile (rectangle plus left disk, minus the notch)."""
    in_rect = (np.abs(x) <= 1.0) & (np.abs(y) <= 0.5)
    in_disk = (x - _CAD_ARC_CENTRE[0]) ** 2 + y**2 <= _CAD_ARC_RADIUS**2
    in_notch = (x > 0.4) & (y > 0.0)
    return (in_rect | in_disk) & ~in_notch


def _cad_boundary_distance(x, y):
    """Exact distance from 2-D points to the profile boundary (5 segments and the arc)."""
    best = np.full(np.shape(x), np.inf)
    for a, b in zip(_CAD_SEG_A, _CAD_SEG_B):
        d = b - a
        t = np.clip(((x - a[0]) * d[0] + (y - a[1]) * d[1]) / (d @ d), 0.0, 1.0)
        best = np.minimum(best, np.hypot(x - a[0] - t * d[0], y - a[1] - t * d[1]))
    # The arc covers the directions with x <= centre; elsewhere its nearest point is an end
    # point, which the top and bottom segments already account for.
    dx = x - _CAD_ARC_CENTRE[0]
    on_arc_side = dx <= 0.0
    arc = np.abs(np.hypot(dx, y - _CAD_ARC_CENTRE[1]) - _CAD_ARC_RADIUS)
    return np.where(on_arc_side, np.minimum(best, arc), best)


def _cad_signed_distance_2d(x, y):
    """Exact 2-D signed distance of the profile (negative inside)."""
    d = _cad_boundary_distance(x, y)
    return np.where(_cad_inside(x, y), -d, d)


def _cad_profile_lengths():
    """Lengths of the boundary pieces: the 5 segments, then the arc."""
    return np.r_[np.linalg.norm(_CAD_SEG_B - _CAD_SEG_A, axis=1), np.pi * _CAD_ARC_RADIUS]


def _cad_profile_area():
    """Area of the profile: rectangle + half disk - notch."""
    return 2.0 * 1.0 + 0.5 * np.pi * _CAD_ARC_RADIUS**2 - 0.6 * 0.5


def _sample_cad_caps(rng, n):
    """``n`` points uniform on the profile, by vectorised rejection from its bounding box."""
    acceptance = _cad_profile_area() / np.prod(_CAD_BOX_HI[:2] - _CAD_BOX_LO[:2])
    batches = [np.empty((0, 2))]  # also covers n == 0
    found = 0
    while found < n:
        # Over-draw a little so that one batch almost always suffices.
        m = int(1.1 * (n - found) / acceptance) + 64
        xy = rng.uniform(_CAD_BOX_LO[:2], _CAD_BOX_HI[:2], (m, 2))
        xy = xy[_cad_inside(xy[:, 0], xy[:, 1])]
        batches.append(xy)
        found += len(xy)
    return np.concatenate(batches)[:n]


def _sample_cad_wall(rng, n):
    """``n`` points uniform on the side wall: arc length along the profile times uniform z."""
    lengths = _cad_profile_lengths()
    ends = np.cumsum(lengths)
    s = rng.uniform(0.0, ends[-1], n)
    piece = np.minimum(np.searchsorted(ends, s, side="right"), len(lengths) - 1)
    local = s - (ends[piece] - lengths[piece])
    z = rng.uniform(-_CAD_HALF_HEIGHT, _CAD_HALF_HEIGHT, n)

    on_arc = piece == len(lengths) - 1
    seg = np.minimum(piece, len(_CAD_SEG_A) - 1)
    a, b = _CAD_SEG_A[seg], _CAD_SEG_B[seg]
    direction = (b - a) / lengths[seg, None]
    # Counter-clockwise traversal: the outward normal is the direction turned clockwise.
    seg_xy = a + local[:, None] * direction
    seg_normal = np.column_stack([direction[:, 1], -direction[:, 0]])
    # The arc runs counter-clockwise from angle pi/2 (top end) to 3 pi/2 (bottom end).
    angle = 0.5 * np.pi + local / _CAD_ARC_RADIUS
    radial = np.column_stack([np.cos(angle), np.sin(angle)])
    arc_xy = _CAD_ARC_CENTRE + _CAD_ARC_RADIUS * radial
    xy = np.where(on_arc[:, None], arc_xy, seg_xy)
    normal = np.where(on_arc[:, None], radial, seg_normal)

    corner_distance = np.linalg.norm(xy[:, None, :] - _CAD_VERTICAL_EDGES, axis=2).min(axis=1)
    edge_distance = np.minimum(_CAD_HALF_HEIGHT - np.abs(z), corner_distance)
    return (np.column_stack([xy, z]), np.column_stack([normal, np.zeros(n)]), edge_distance)


def cad_part(n_points=100000, noise=0.005, seed=0):
    """A CAD-like part with sharp edges, a concave corner and a curved patch.

    The part is the extrusion along ``z`` (``z`` in ``[-0.3, 0.3]``) of the 2-D profile
    ``([-1, 1] x [-0.5, 0.5]  union  disk((-1, 0), 0.5))  minus  [0.4, 1] x [0, 0.5]``, then
    translated to centre its bounding box at the origin and scaled uniformly so that the box
    diagonal is 1. It is the library's built-in default input.

    Parameters
    ----------
    n_points, seed
        As in :func:`plane`.
    noise : float, optional
        Noise std as a fraction of the bounding-box diagonal (1); may be 0.

    Returns
    -------
    SyntheticCloud
        Sharp edges: the whole profile boundary on both caps (90 degrees) and the vertical
        edges at ``(1, -0.5)``, ``(1, 0)``, ``(0.4, 0)`` (concave, 270 degrees) and
        ``(0.4, 0.5)``. Where the half-disk meets the top and bottom faces the surface is
        tangent-continuous, so that is not an edge.

    Raises
    ------
    TypeError
        If an argument has the wrong type.
    ValueError
        If ``n_points < 1``, ``noise`` is negative or not finite, or ``seed < 0``.

    Notes
    -----
    Counts are split between the two caps and the side wall by a multinomial draw over their
    areas. Caps are sampled by vectorised rejection from the profile's bounding rectangle with
    an exact inside test; the wall by a uniform arc-length position along the profile boundary
    times a uniform ``z``. ``edge_distance`` is exact: on a cap it is the 2-D distance to the
    profile boundary (the rim of that cap; everything else is farther), on the wall the smaller
    of the distance to the nearer rim (``0.3 - |z|``) and to the vertical edges.
    ``surface_distance`` is the exact extrusion SDF built from the exact 2-D signed distance of
    the profile (distance to its boundary pieces, signed by the inside test), which, unlike
    min/max combinations of primitive SDFs, is also exact next to the notch.
    """
    h = _CAD_HALF_HEIGHT
    area = _cad_profile_area()
    rng, noise, (n_wall, n_top, n_bottom) = _start(
        n_points, noise, seed, [_cad_profile_lengths().sum() * 2.0 * h, area, area])

    cap_xy = _sample_cad_caps(rng, n_top + n_bottom)
    up = np.r_[np.ones(n_top), -np.ones(n_bottom)]
    caps = np.column_stack([cap_xy, h * up])
    cap_normals = np.column_stack([np.zeros((len(up), 2)), up])
    cap_edge = _cad_boundary_distance(cap_xy[:, 0], cap_xy[:, 1])
    wall, wall_normals, wall_edge = _sample_cad_wall(rng, n_wall)

    clean = (np.concatenate([caps, wall]) - _CAD_CENTRE) * _CAD_SCALE

    def distance(q):
        p = q / _CAD_SCALE + _CAD_CENTRE
        return _CAD_SCALE * _extrusion_distance(_cad_signed_distance_2d(p[:, 0], p[:, 1]),
                                                p[:, 2], h)

    diagonal = float(np.linalg.norm((_CAD_BOX_HI - _CAD_BOX_LO) * _CAD_SCALE))
    return _finish("cad_part", rng, noise, diagonal, clean,
                   np.concatenate([cap_normals, wall_normals]),
                   _CAD_SCALE * np.concatenate([cap_edge, wall_edge]), distance)


GENERATORS = {
    "plane": plane,
    "sphere": sphere,
    "cylinder": cylinder,
    "cube": cube,
    "cad_part": cad_part,
}


def make(name, **kwargs):
    """Build a synthetic cloud by generator name.

    Parameters
    ----------
    name : str
        A key of :data:`GENERATORS`.
    **kwargs
        Passed on to the generator (``n_points``, ``noise``, ``seed``, shape parameters).

    Returns
    -------
    SyntheticCloud
        The generator's result.

    Raises
    ------
    TypeError
        If ``name`` is not a string, or the generator rejects a keyword.
    ValueError
        If ``name`` is not a known generator (the message lists the valid names), or the
        generator rejects a value.
    """
    if not isinstance(name, str):
        raise TypeError(f"name must be a string, got {name!r}")
    if name not in GENERATORS:
        raise ValueError(f"unknown synthetic cloud {name!r}; valid names: "
                         f"{', '.join(sorted(GENERATORS))}")
    return GENERATORS[name](**kwargs)
