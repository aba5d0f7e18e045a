"""The denoisers a user would pick instead of ours, run on a numpy point cloud.

Thin wrappers around three libraries, so that a benchmark can print their rows next to ours:

* **CGAL** (``pip install cgal``, the SWIG bindings, modules ``CGAL.CGAL_Point_set_3`` and
  ``CGAL.CGAL_Point_set_processing_3``): :func:`cgal_jet` (``jet_smooth_point_set``) and
  :func:`cgal_bilateral` (``jet_estimate_normals`` + ``mst_orient_normals`` +
  ``bilateral_smooth_point_set``).
* **MeshLab** (``pip install pymeshlab``): :func:`meshlab_rimls` and :func:`meshlab_apss`
  (``compute_mls_projection_rimls`` / ``compute_mls_projection_apss``, projecting the cloud onto
  the MLS surface it defines).
* **Open3D** (``pip install open3d``, 0.20 or later; on Linux it needs the system's
  ``libusb-1.0``): :func:`open3d_mls` (``PointCloud.smooth_mls``, a tangent plane through
  each point's neighbours) and :func:`open3d_bilateral` (``PointCloud.smooth_bilateral``, a
  bilateral average of the neighbours).

Every wrapper takes ``points``, an ``(n, 3)`` array (read, never modified), plus the method's own
parameters, and returns a :class:`PeerResult` whose ``points`` are in the *same order* as the
input. ``seconds`` times the library's denoising calls only (normal estimation included where the
method needs it, see ``stage_seconds``); moving the data between numpy and the library's
containers is timed apart in ``convert_seconds``.

:data:`PEERS` maps display names to ready-made ``points -> PeerResult`` callables for the installed
libraries, and :func:`available` says which libraries import. ``python -m benchmarks.peers`` runs
them all once on a noisy sphere and measures the conversion cost.

Errors: a missing library raises :class:`ImportError` carrying the ``pip install`` command; an
exception inside a library is re-raised as :class:`RuntimeError` naming the peer and the call; a
library that drops or reorders points is mapped back by index where it can be and otherwise
raises :class:`RuntimeError`. (Crashes in native code cannot be caught; the one crash we found,
in MeshLab's MLS filters, is avoided, see :func:`_meshlab_mls`.)

CGAL conversion (measured by :func:`measure_cgal_conversion`, 100,000 points, 2-core machine).
The bindings have no numpy path. The fastest way in is ``insert_range`` with a flat Python list
``[x0, y0, z0, x1, ...]`` (it rejects numpy arrays and lists of ``Point_3``): ~0.02 s, against
~0.3 s for per-point ``insert(Point_3(x, y, z))``. The fastest way out is ``Point_set_3.write`` to
a binary PLY file in a RAM-backed temporary directory, parsed with ``numpy.frombuffer``: ~0.03 s
for points, ~0.06 s with normals, against ~0.34 s for iterating ``points()`` and ``normals()``
with one ``x()``/``y()``/``z()`` call per coordinate (kept as the fallback). Both give rows in the
point set's index order; ``indices()`` (~0.02 s) gives each row's insertion index, which maps the
rows back to input order.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import os
import tempfile
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, Mapping, Optional, Tuple

import numpy as np
from pykdtree.kdtree import KDTree

__all__ = [
    "PeerResult",
    "PEERS",
    "available",
    "cgal_jet",
    "cgal_bilateral",
    "meshlab_rimls",
    "meshlab_apss",
    "open3d_mls",
    "open3d_bilateral",
    "measure_cgal_conversion",
    "noisy_sphere",
]

_PIP = {"cgal": "pip install cgal", "pymeshlab": "pip install pymeshlab",
        "open3d": "pip install open3d"}
#: The libraries the wrappers call, by the name :func:`available` reports.
LIBRARIES = ("cgal", "pymeshlab", "open3d")


@dataclass(frozen=True)
class PeerResult:
    """What a peer returns.

    Attributes:
        points: ``(n, 3)`` float64, the denoised points, row ``i`` comes from input row ``i``.
        normals: ``(n, 3)`` float64 unit normals in the same order, or ``None`` when the method
            does not produce them.
        seconds: wall time of the library's denoising calls only (normal estimation and
            orientation included when the method runs them; conversions excluded).
        convert_seconds: wall time spent moving the data between numpy and the library's
            containers (both ways), and setting those containers up.
        name: the peer, e.g. ``"CGAL jet"``.
        stage_seconds: ``seconds`` split by library call, e.g. ``{"normals": .., "smooth": ..}``.
        notes: anything the caller should know about this run (e.g. restored points).
        failed: how many points the library could not process and that were left at their
            input position (MeshLab's MLS projection yields NaN for a few points; see
            ``on_failure`` in :func:`meshlab_rimls`). Always 0 for the CGAL peers.
    """

    points: np.ndarray
    normals: Optional[np.ndarray]
    seconds: float
    convert_seconds: float
    name: str = ""
    stage_seconds: Mapping[str, float] = field(default_factory=dict)
    notes: str = ""
    failed: int = 0


# --------------------------------------------------------------------------------------------------
# Library loading


def _import_cgal():
    """The two CGAL binding modules, or ImportError with the pip command."""
    try:
        from CGAL import CGAL_Point_set_3, CGAL_Point_set_processing_3
    except ImportError as error:
        raise ImportError(
            f"the CGAL Python bindings are not installed ({error}); install them with "
            f"`{_PIP['cgal']}`") from error
    return CGAL_Point_set_3, CGAL_Point_set_processing_3


def _import_pymeshlab():
    """The pymeshlab module, or ImportError with the pip command."""
    try:
        import pymeshlab
    except ImportError as error:
        raise ImportError(
            f"pymeshlab is not installed ({error}); install it with `{_PIP['pymeshlab']}`"
        ) from error
    return pymeshlab


def _import_open3d():
    """The open3d module (0.20 or later: ``smooth_mls``), or ImportError with the pip command."""
    try:
        import open3d
    except ImportError as error:
        raise ImportError(
            f"open3d is not installed or cannot load ({error}); install it with "
            f"`{_PIP['open3d']}` (on Linux it also needs the system's libusb-1.0)") from error
    if not hasattr(open3d.geometry.PointCloud, "smooth_mls"):
        raise ImportError(f"open3d {open3d.__version__} has no smooth_mls; install 0.20 or "
                          f"later with `{_PIP['open3d']}`")
    return open3d


@functools.lru_cache(maxsize=None)
def _can_import(library: str) -> bool:
    loader = {"cgal": _import_cgal, "pymeshlab": _import_pymeshlab,
              "open3d": _import_open3d}[library]
    try:
        loader()
    except ImportError:
        return False
    return True


def available() -> Dict[str, bool]:
    """``{"cgal": bool, "pymeshlab": bool, "open3d": bool}``: whether each library imports."""
    return {library: _can_import(library) for library in LIBRARIES}


# --------------------------------------------------------------------------------------------------
# Helpers


def _check_points(points, peer: str) -> np.ndarray:
    """The input as a C-contiguous float64 (n, 3) array; a copy only when needed (never written)."""
    array = np.ascontiguousarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{peer}: points must have shape (n, 3), got {np.shape(points)}")
    if array.shape[0] == 0:
        raise ValueError(f"{peer}: points is empty")
    if not np.isfinite(array).all():
        raise ValueError(f"{peer}: points contain NaN or infinite coordinates")
    return array


def _check_k(k: int, n: int, peer: str, what: str = "k") -> int:
    k = int(k)
    if k < 6:
        raise ValueError(f"{peer}: {what}={k} is too small (a degree-2 jet fit needs 6 neighbours)")
    if k >= n:
        raise ValueError(f"{peer}: {what}={k} needs more than {k} points, got {n}")
    return k


def _check_passes(points, k: int, passes: int, peer: str):
    """What every smoothing wrapper checks first: ``(points, n, k, passes)`` with the points as
    :func:`_check_points` gives them, ``k`` as :func:`_check_k` and ``passes`` at least 1."""
    points = _check_points(points, peer)
    k = _check_k(k, len(points), peer)
    if int(passes) < 1:
        raise ValueError(f"{peer}: passes must be >= 1, got {passes}")
    return points, len(points), k, int(passes)


def _check_finite(array: np.ndarray, peer: str, what: str) -> None:
    bad = int((~np.isfinite(array)).any(axis=1).sum())
    if bad:
        raise RuntimeError(f"{peer}: the library returned {bad} {what} with NaN or infinite "
                           f"coordinates out of {len(array)}")


def _keep_input_where_failed(out, out_normals, points, input_normals):
    """Rows where the projection failed (non-finite point or normal, zero normal) get the input
    point and normal back. Returns the patched copies and the number of such rows."""
    failed = ~(np.isfinite(out).all(axis=1) & np.isfinite(out_normals).all(axis=1))
    failed |= ~(np.linalg.norm(np.where(failed[:, None], 1.0, out_normals), axis=1) > 0)
    count = int(failed.sum())
    if count:
        out, out_normals = out.copy(), out_normals.copy()
        out[failed] = points[failed]
        out_normals[failed] = input_normals[failed]
    return out, out_normals, count


def _unit(vectors: np.ndarray, peer: str) -> np.ndarray:
    length = np.linalg.norm(vectors, axis=1)
    bad = int((~(length > 0)).sum())
    if bad:
        raise RuntimeError(f"{peer}: {bad} normals have zero length")
    return vectors / length[:, None]


class _Timer:
    """Accumulates wall time per label: ``with timer("smooth"): ...``."""

    def __init__(self):
        self.seconds: Dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, label: str):
        started = time.perf_counter()
        try:
            yield
        finally:
            elapsed = time.perf_counter() - started
            self.seconds[label] = self.seconds.get(label, 0.0) + elapsed

    def total(self) -> float:
        return float(sum(self.seconds.values()))


def _library_call(peer: str, what: str, call: Callable, *args, **kwargs):
    """Run one library call, turning any exception it raises into RuntimeError naming the peer."""
    try:
        return call(*args, **kwargs)
    except Exception as error:  # noqa: BLE001 - re-raised with the peer's name
        raise RuntimeError(f"{peer}: {what} failed: {type(error).__name__}: {error}") from error


# --------------------------------------------------------------------------------------------------
# CGAL <-> numpy

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}


def _scratch_dir() -> Optional[str]:
    """A RAM-backed directory for the PLY round trip when there is one."""
    return "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None


def _parse_binary_ply_vertices(data: bytes) -> np.ndarray:
    """The vertex element of a binary little-endian PLY file (as CGAL writes it), as records."""
    marker = data.find(b"end_header")
    if marker < 0:
        raise ValueError("no end_header in PLY data")
    body = data.index(b"\n", marker) + 1
    lines = data[:marker].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in [line.strip() for line in lines]:
        raise ValueError("PLY data is not binary_little_endian")
    count, fields, element = None, [], None
    for line in lines:
        words = line.split()
        if not words:
            continue
        if words[0] == "element":
            element = words[1]
            if element == "vertex":
                count = int(words[2])
            elif int(words[2]) and count is not None:
                raise ValueError(f"unexpected non-empty PLY element {words[1]!r}")
        elif words[0] == "property" and element == "vertex":
            if words[1] == "list":
                raise ValueError("list property in the PLY vertex element")
            fields.append((words[2], _PLY_TYPES[words[1]]))
    if count is None:
        raise ValueError("no vertex element in PLY data")
    return np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=body)


def _to_point_set(points: np.ndarray):
    """A CGAL ``Point_set_3`` holding the rows of ``points`` (index i = row i)."""
    point_set_3, _ = _import_cgal()
    point_set = point_set_3.Point_set_3()
    # insert_range takes a flat sequence of Python floats (x0, y0, z0, x1, ...); it is the only
    # bulk insertion the bindings offer.
    point_set.insert_range(points.ravel().tolist())
    if point_set.size() != len(points):
        raise RuntimeError(f"CGAL insert_range stored {point_set.size()} of {len(points)} points")
    return point_set


def _read_point_set_ply(point_set) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Points (and normals if present) in index order through a binary PLY round trip."""
    handle, path = tempfile.mkstemp(suffix=".ply", dir=_scratch_dir())
    os.close(handle)
    try:
        if not point_set.write(path):
            raise OSError(f"Point_set_3.write({path!r}) returned False")
        with open(path, "rb") as stream:
            data = stream.read()
    finally:
        os.unlink(path)
    vertices = _parse_binary_ply_vertices(data)
    points = np.column_stack([vertices["x"], vertices["y"], vertices["z"]]).astype(np.float64)
    normals = None
    if "nx" in vertices.dtype.names:
        normals = np.column_stack([vertices["nx"], vertices["ny"], vertices["nz"]]).astype(
            np.float64)
    return points, normals


def _read_point_set_iter(point_set) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Points (and normals if present) in index order, one SWIG call per coordinate (slow)."""
    count = point_set.size()
    points = np.fromiter((c for p in point_set.points() for c in (p.x(), p.y(), p.z())),
                         dtype=np.float64, count=3 * count).reshape(count, 3)
    normals = None
    if point_set.has_normal_map():
        normals = np.fromiter((c for v in point_set.normals() for c in (v.x(), v.y(), v.z())),
                              dtype=np.float64, count=3 * count).reshape(count, 3)
    return points, normals


def _from_point_set(point_set, n: int, peer: str, method: str = "ply"
                    ) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Points and normals back in input order (row i = the point inserted i-th).

    Raises RuntimeError if points were dropped. The point set must not have had its garbage
    collected (none of the wrapped functions do), so that an index is still the insertion row.
    """
    if point_set.size() != n or point_set.number_of_removed_points():
        raise RuntimeError(f"{peer}: CGAL kept {point_set.size()} of {n} points "
                           f"({point_set.number_of_removed_points()} removed)")
    rows = np.fromiter(point_set.indices(), dtype=np.int64, count=n)
    if method == "ply":
        try:
            points, normals = _read_point_set_ply(point_set)
        except (OSError, ValueError, KeyError):
            points, normals = _read_point_set_iter(point_set)
    else:
        points, normals = _read_point_set_iter(point_set)
    if len(points) != n or (normals is not None and len(normals) != n):
        raise RuntimeError(f"{peer}: read back {len(points)} points from CGAL, expected {n}")
    if not np.array_equal(np.sort(rows), np.arange(n)):
        raise RuntimeError(f"{peer}: CGAL point indices are no longer 0..{n - 1}; cannot map the "
                           "output back to input order")
    out_points = np.empty_like(points)
    out_points[rows] = points
    out_normals = None
    if normals is not None:
        out_normals = np.empty_like(normals)
        out_normals[rows] = normals
    return out_points, out_normals


def measure_cgal_conversion(n: int = 100_000, seed: int = 0) -> Dict[str, float]:
    """Seconds to move ``n`` points (with normals) into and out of a CGAL ``Point_set_3``.

    Returns the bulk path the wrappers use (``to_cgal_insert_range``, ``from_cgal_ply`` with
    normals, ``from_cgal_ply_points_only``, ``indices``) next to the per-point alternatives
    (``to_cgal_insert_point_3``, ``from_cgal_iterate``).
    """
    point_set_3, processing = _import_cgal()
    from CGAL.CGAL_Kernel import Point_3

    points = noisy_sphere(n, seed=seed)
    times = {}
    started = time.perf_counter()
    point_set = _to_point_set(points)
    times["to_cgal_insert_range"] = time.perf_counter() - started

    started = time.perf_counter()
    slow = point_set_3.Point_set_3()
    slow.reserve(n)
    for x, y, z in points.tolist():
        slow.insert(Point_3(x, y, z))
    times["to_cgal_insert_point_3"] = time.perf_counter() - started
    del slow

    started = time.perf_counter()
    back, _ = _from_point_set(point_set, n, "conversion", method="ply")
    times["from_cgal_ply_points_only"] = time.perf_counter() - started
    assert np.array_equal(back, points)

    processing.pca_estimate_normals(point_set, 10)  # adds a normal map
    started = time.perf_counter()
    np.fromiter(point_set.indices(), dtype=np.int64, count=n)
    times["indices"] = time.perf_counter() - started
    started = time.perf_counter()
    _from_point_set(point_set, n, "conversion", method="ply")
    times["from_cgal_ply"] = time.perf_counter() - started
    started = time.perf_counter()
    _from_point_set(point_set, n, "conversion", method="iterate")
    times["from_cgal_iterate"] = time.perf_counter() - started
    return times


# --------------------------------------------------------------------------------------------------
# CGAL peers


def cgal_jet(points, k: int = 48, passes: int = 1, *, neighbor_radius: float = 0.0,
             degree_fitting: int = 2, degree_monge: int = 2) -> PeerResult:
    """CGAL jet smoothing: ``jet_smooth_point_set`` applied ``passes`` times.

    Each pass fits a degree-``degree_fitting`` jet (Monge form of degree ``degree_monge``) to the
    ``k`` nearest neighbours of every point and projects the point onto it. The call is
    ``CGAL_Point_set_processing_3.jet_smooth_point_set(point_set, k, neighbor_radius,
    degree_fitting, degree_monge)`` (``neighbor_radius=0`` means plain kNN; a positive radius uses
    a ball query capped at ``k`` points). No normals are produced.
    """
    peer = "CGAL jet"
    points, n, k, passes = _check_passes(points, k, passes, peer)
    _, processing = _import_cgal()
    convert, run = _Timer(), _Timer()
    with convert("to_cgal"):
        point_set = _to_point_set(points)
    with run("smooth"):
        for _ in range(passes):
            _library_call(peer, "jet_smooth_point_set", processing.jet_smooth_point_set,
                          point_set, k, float(neighbor_radius), int(degree_fitting),
                          int(degree_monge))
    with convert("from_cgal"):
        out, _ = _from_point_set(point_set, n, peer)
    _check_finite(out, peer, "points")
    return PeerResult(points=out, normals=None, seconds=run.total(),
                      convert_seconds=convert.total(), name=peer, stage_seconds=run.seconds)


def cgal_bilateral(points, k: int = 120, passes: int = 3, sharpness_angle: float = 25.0, *,
                   normal_k: Optional[int] = None, neighbor_radius: float = 0.0) -> PeerResult:
    """CGAL bilateral (edge-aware) smoothing with the normals it needs.

    Calls, on one ``Point_set_3``:

    1. ``jet_estimate_normals(point_set, normal_k)`` (adds the normal map),
    2. ``mst_orient_normals(point_set, normal_k)`` (orients them along a minimum spanning tree;
       the bindings then *remove* points whose normal could not be oriented: we put them back with
       ``cancel_removals()``, keeping their unoriented normal, and say how many in ``notes``),
    3. ``bilateral_smooth_point_set(point_set, k, neighbor_radius, sharpness_angle)`` ``passes``
       times (each pass also updates the normals).

    ``normal_k`` defaults to ``k``, the smoothing neighbourhood, so one scale drives the whole
    method as the brief asks (nothing in the bindings requires a different one). It is costly at
    ``k=120``: on 100,000 points the MST orientation takes ~14 s against ~2 s at ``normal_k=18``;
    pass ``normal_k=18`` for the cheaper variant.

    Beware of the neighbourhood size relative to the curvature: on a unit sphere of 3,000 points
    ``k=120`` covers a cap of radius ~0.4 and each pass pushes the points outwards by ~0.02 (the
    error grows), while on dense scans (the setting CGAL's example targets) it smooths well.

    Returns the smoothed points and the final unit normals.
    """
    peer = "CGAL bilateral"
    points, n, k, passes = _check_passes(points, k, passes, peer)
    normal_k = k if normal_k is None else _check_k(normal_k, n, peer, "normal_k")
    _, processing = _import_cgal()
    convert, run = _Timer(), _Timer()
    notes = ""
    with convert("to_cgal"):
        point_set = _to_point_set(points)
    with run("normals"):
        _library_call(peer, "jet_estimate_normals", processing.jet_estimate_normals,
                      point_set, normal_k, float(neighbor_radius))
    with run("orient"):
        _library_call(peer, "mst_orient_normals", processing.mst_orient_normals,
                      point_set, normal_k, float(neighbor_radius))
    unoriented = point_set.number_of_removed_points()
    if unoriented:
        point_set.cancel_removals()
        notes = (f"mst_orient_normals could not orient {unoriented} of {n} normals; those points "
                 "were restored and keep an unoriented normal")
    with run("smooth"):
        for _ in range(passes):
            _library_call(peer, "bilateral_smooth_point_set",
                          processing.bilateral_smooth_point_set, point_set, k,
                          float(neighbor_radius), float(sharpness_angle))
    with convert("from_cgal"):
        out, normals = _from_point_set(point_set, n, peer)
    if normals is None:
        raise RuntimeError(f"{peer}: the point set lost its normal map")
    _check_finite(out, peer, "points")
    _check_finite(normals, peer, "normals")
    return PeerResult(points=out, normals=_unit(normals, peer), seconds=run.total(),
                      convert_seconds=convert.total(), name=peer, stage_seconds=run.seconds,
                      notes=notes)


# --------------------------------------------------------------------------------------------------
# MeshLab peers


def _meshlab_mls(peer: str, filter_name: str, points, normals, filter_parameters: dict,
                 normal_k: int, normal_smooth_iters: int, on_failure: str) -> PeerResult:
    """Project a point cloud onto the MLS surface it defines, with one pymeshlab filter.

    Layers: the *control* layer (the MLS source: the input points with normals) and the *proxy*
    layer (a copy, whose vertices are projected in place, in their order; ``maxsubdivisions=0``
    so no vertex is added). The control layer must be the *current* one: the filter computes the
    per-vertex radius it needs on the current layer only, and with a radius-less control layer
    (or with ``controlmesh == proxymesh``, which makes it work on a temporary clone) pymeshlab
    2025.7 segfaults in ``MlsSurface::computeNeighborhood``.

    A projection that fails leaves NaN in the proxy layer (3 points of a 100,000-point noisy
    sphere with APSS at the defaults). ``on_failure="keep_input"`` puts the input point and its
    (given or estimated) normal back in those rows and counts them in ``PeerResult.failed`` and
    ``notes``; ``on_failure="raise"`` raises RuntimeError instead.
    """
    if on_failure not in ("keep_input", "raise"):
        raise ValueError(f"{peer}: on_failure must be 'keep_input' or 'raise', got {on_failure!r}")
    points = _check_points(points, peer)
    n = len(points)
    pymeshlab = _import_pymeshlab()
    convert, run = _Timer(), _Timer()
    with convert("to_meshlab"):
        mesh_set = pymeshlab.MeshSet()
        if normals is None:
            mesh_set.add_mesh(pymeshlab.Mesh(vertex_matrix=points), "control")
        else:
            given = np.ascontiguousarray(normals, dtype=np.float64)
            if given.shape != points.shape:
                raise ValueError(f"{peer}: normals must have shape {points.shape}, "
                                 f"got {given.shape}")
            if not np.isfinite(given).all():
                raise ValueError(f"{peer}: normals contain NaN or infinite values")
            length = np.linalg.norm(given, axis=1)
            if not (length > 0).all():
                raise ValueError(f"{peer}: some normals have zero length")
            mesh_set.add_mesh(pymeshlab.Mesh(vertex_matrix=points,
                                             v_normals_matrix=given / length[:, None]), "control")
        control = mesh_set.current_mesh_id()
    if normals is None:
        normal_k = _check_k(normal_k, n, peer, "normal_k")
        with run("normals"):
            _library_call(peer, "compute_normal_for_point_clouds",
                          mesh_set.compute_normal_for_point_clouds, k=int(normal_k),
                          smoothiter=int(normal_smooth_iters), flipflag=False)
    with convert("to_meshlab"):
        _library_call(peer, "generate_copy_of_current_mesh", mesh_set.generate_copy_of_current_mesh)
        proxy = mesh_set.current_mesh_id()
        if proxy == control or mesh_set.mesh(proxy).vertex_number() != n:
            raise RuntimeError(f"{peer}: could not make a copy of the cloud to project")
        mesh_set.set_current_mesh(control)
    with run("project"):
        _library_call(peer, filter_name, getattr(mesh_set, filter_name), controlmesh=control,
                      proxymesh=proxy, selectiononly=False, maxsubdivisions=0,
                      **filter_parameters)
    with convert("from_meshlab"):
        projected = mesh_set.mesh(proxy)
        out = np.array(projected.vertex_matrix(), dtype=np.float64)
        out_normals = np.array(projected.vertex_normal_matrix(), dtype=np.float64)
    if out.shape != (n, 3) or out_normals.shape != (n, 3):
        raise RuntimeError(f"{peer}: {filter_name} returned {len(out)} points for {n}")
    notes, failed = "", 0
    if on_failure == "raise":
        _check_finite(out, peer, "points")
        _check_finite(out_normals, peer, "normals")
    else:
        with convert("from_meshlab"):
            input_normals = np.array(mesh_set.mesh(control).vertex_normal_matrix(),
                                     dtype=np.float64)
        out, out_normals, failed = _keep_input_where_failed(out, out_normals, points,
                                                            input_normals)
        if failed:
            notes = (f"{filter_name} failed to project {failed} of {n} points (NaN); they keep "
                     "their input position and normal")
    return PeerResult(points=out, normals=_unit(out_normals, peer), seconds=run.total(),
                      convert_seconds=convert.total(), name=peer, stage_seconds=run.seconds,
                      notes=notes, failed=failed)


def meshlab_rimls(points, normals=None, *, filter_scale: float = 2.0,
                  max_projection_iters: int = 15, projection_accuracy: float = 1e-4,
                  sigma_n: float = 0.75, max_refitting_iters: int = 3, normal_k: int = 10,
                  normal_smooth_iters: int = 0, on_failure: str = "keep_input") -> PeerResult:
    """MeshLab's Robust Implicit MLS projection (Öztireli et al. 2009) of the cloud onto itself.

    ``MeshSet.compute_mls_projection_rimls(controlmesh, proxymesh, selectiononly=False,
    maxsubdivisions=0, filterscale, projectionaccuracy, maxprojectioniters, sigman,
    maxrefittingiters)``; the keyword defaults here are MeshLab's. ``filter_scale`` is relative
    to the per-vertex radius (local point spacing) MeshLab estimates; ``sigma_n`` is the
    sharpness (0.5 sharp .. 2 smooth).

    RIMLS needs oriented normals: pass ``normals`` ((n, 3), normalised here) or leave ``None`` to
    have MeshLab estimate and orient them with ``compute_normal_for_point_clouds(k=normal_k,
    smoothiter=normal_smooth_iters, flipflag=False)`` (its defaults), timed as ``"normals"``.
    Returns the projected points and the MLS gradient normals. Points whose projection fails
    (NaN) keep their input position (``on_failure="keep_input"``, counted in ``failed``) or make
    the call raise RuntimeError (``on_failure="raise"``).

    At the defaults the filter's support is a couple of point spacings: where the noise is as
    large as the spacing (100,000 points on a unit sphere with noise 0.01) RIMLS barely
    smooths (mean |r-1| 0.0080 -> 0.0077); raise ``filter_scale`` for such data.
    """
    parameters = dict(filterscale=float(filter_scale),
                      projectionaccuracy=float(projection_accuracy),
                      maxprojectioniters=int(max_projection_iters), sigman=float(sigma_n),
                      maxrefittingiters=int(max_refitting_iters))
    return _meshlab_mls("MeshLab RIMLS", "compute_mls_projection_rimls", points, normals,
                        parameters, normal_k, normal_smooth_iters, on_failure)


def meshlab_apss(points, normals=None, *, filter_scale: float = 2.0,
                 max_projection_iters: int = 15, projection_accuracy: float = 1e-4,
                 spherical_parameter: float = 1.0, accurate_normal: bool = True,
                 normal_k: int = 10, normal_smooth_iters: int = 0,
                 on_failure: str = "keep_input") -> PeerResult:
    """MeshLab's Algebraic Point Set Surfaces projection (Guennebaud & Gross 2007) onto itself.

    ``MeshSet.compute_mls_projection_apss(controlmesh, proxymesh, selectiononly=False,
    maxsubdivisions=0, filterscale, projectionaccuracy, maxprojectioniters, sphericalparameter,
    accuratenormal)``; the keyword defaults here are MeshLab's. ``spherical_parameter`` 1 fits
    spheres, 0 planes.

    Normals and ``on_failure`` as in :func:`meshlab_rimls`. Returns the projected points and
    the MLS normals.
    """
    parameters = dict(filterscale=float(filter_scale),
                      projectionaccuracy=float(projection_accuracy),
                      maxprojectioniters=int(max_projection_iters),
                      sphericalparameter=float(spherical_parameter),
                      accuratenormal=bool(accurate_normal))
    return _meshlab_mls("MeshLab APSS", "compute_mls_projection_apss", points, normals,
                        parameters, normal_k, normal_smooth_iters, on_failure)


# --------------------------------------------------------------------------------------------------
# The table of peers


# --------------------------------------------------------------------------------------------------
# Open3D peers


def _open3d_cloud(points, convert):
    """``(open3d, PointCloud of points)``, the copy timed as conversion."""
    open3d = _import_open3d()
    with convert("to_open3d"):
        # Open3D takes only a writeable buffer; it copies it, the input stays untouched.
        cloud = open3d.geometry.PointCloud(open3d.utility.Vector3dVector(points.copy()))
    return open3d, cloud


def _open3d_points(cloud, n: int, peer: str, convert) -> np.ndarray:
    """The cloud's points as a float64 array, checked to be ``n`` rows (the methods keep every
    point in place)."""
    with convert("from_open3d"):
        out = np.array(cloud.points, dtype=np.float64)
    if out.shape != (n, 3):
        raise RuntimeError(f"{peer}: the library returned {out.shape[0]} points for {n}")
    _check_finite(out, peer, "points")
    return out


def open3d_mls(points, k: int = 48, passes: int = 1) -> PeerResult:
    """Open3D's MLS-style smoothing: ``PointCloud.smooth_mls`` applied ``passes`` times.

    Each pass fits a plane (PCA, uniform weights under a kNN search) to the ``k`` nearest
    neighbours of every point and projects the point onto it
    (``smooth_mls(KDTreeSearchParamKNN(k))``). No normals are produced.
    """
    peer = "Open3D MLS"
    points, n, k, passes = _check_passes(points, k, passes, peer)
    convert, run = _Timer(), _Timer()
    open3d, cloud = _open3d_cloud(points, convert)
    search = open3d.geometry.KDTreeSearchParamKNN(k)
    with run("smooth"):
        for _ in range(passes):
            cloud = _library_call(peer, "smooth_mls", cloud.smooth_mls, search)
    out = _open3d_points(cloud, n, peer, convert)
    return PeerResult(points=out, normals=None, seconds=run.total(),
                      convert_seconds=convert.total(), name=peer, stage_seconds=run.seconds)


def open3d_bilateral(points, k: int = 48, passes: int = 1, sigma_s: float = 0.5,
                     sigma_r: float = 0.3) -> PeerResult:
    """Open3D's bilateral smoothing: ``PointCloud.smooth_bilateral`` applied ``passes`` times.

    The normals are estimated first over the same ``k`` nearest neighbours
    (``estimate_normals``; the method would otherwise estimate them at Open3D's defaults). Each
    pass then moves every point to the average of its ``k`` nearest, weighted by
    ``exp(-d^2 / 2 sigma_s^2) * exp(-((p_i - p_j) . n_i)^2 / 2 sigma_r^2)``. ``sigma_s`` and
    ``sigma_r`` are given as multiples of the cloud's median distance to its ``k``-th nearest
    neighbour (measured with pykdtree and timed as the stage ``"spacing"``), so that one setting
    suits every scale. Returns the smoothed points and Open3D's final normals.
    """
    peer = "Open3D bilateral"
    points, n, k, passes = _check_passes(points, k, passes, peer)
    if not (sigma_s > 0 and sigma_r > 0):
        raise ValueError(f"{peer}: sigma_s and sigma_r must be positive, got {sigma_s}, "
                         f"{sigma_r}")
    convert, run = _Timer(), _Timer()
    open3d, cloud = _open3d_cloud(points, convert)
    search = open3d.geometry.KDTreeSearchParamKNN(k)
    with run("spacing"):
        spacing = float(np.median(KDTree(points).query(points, k=k)[0][:, -1]))
    with run("normals"):
        _library_call(peer, "estimate_normals", cloud.estimate_normals, search)
    with run("smooth"):
        for _ in range(passes):
            cloud = _library_call(peer, "smooth_bilateral", cloud.smooth_bilateral, search,
                                  sigma_s * spacing, sigma_r * spacing)
    out = _open3d_points(cloud, n, peer, convert)
    with convert("from_open3d"):
        normals = _unit(np.array(cloud.normals, dtype=np.float64), peer)
    return PeerResult(points=out, normals=normals, seconds=run.total(),
                      convert_seconds=convert.total(), name=peer, stage_seconds=run.seconds)


def _passes(count: int) -> str:
    return f"{count} pass" if count == 1 else f"{count} passes"


def _build_peers() -> Dict[str, Callable[[np.ndarray], PeerResult]]:
    peers: Dict[str, Callable[[np.ndarray], PeerResult]] = {}
    have = available()
    if have["cgal"]:
        for k in (24, 48, 96):
            for passes in (1, 2):
                peers[f"CGAL jet (k={k}, {_passes(passes)})"] = functools.partial(
                    cgal_jet, k=k, passes=passes)
        for k in (60, 120):
            peers[f"CGAL bilateral (k={k}, {_passes(3)})"] = functools.partial(
                cgal_bilateral, k=k, passes=3)
    if have["pymeshlab"]:
        peers["MeshLab RIMLS (defaults)"] = meshlab_rimls
        peers["MeshLab APSS (defaults)"] = meshlab_apss
    if have["open3d"]:
        for k in (24, 48, 96):
            for passes in (1, 2):
                peers[f"Open3D MLS (k={k}, {_passes(passes)})"] = functools.partial(
                    open3d_mls, k=k, passes=passes)
        peers[f"Open3D bilateral (k=48, {_passes(1)})"] = open3d_bilateral
    return peers


#: Display name -> ``points -> PeerResult``, for the installed libraries only.
PEERS: Dict[str, Callable[[np.ndarray], PeerResult]] = _build_peers()


# --------------------------------------------------------------------------------------------------
# Command line: one run of each peer on a noisy sphere


def noisy_sphere(n: int, noise: float = 0.01, seed: int = 0) -> np.ndarray:
    """``n`` uniform points on the unit sphere, plus isotropic Gaussian noise of sd ``noise``."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions + rng.normal(0.0, noise, size=(n, 3))


def _radial_error(points: np.ndarray) -> float:
    return float(np.abs(np.linalg.norm(points, axis=1) - 1.0).mean())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000, help="points on the sphere")
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--only", nargs="*", default=None, help="substrings of peer names to run")
    args = parser.parse_args(argv)
    print("available:", available())
    if available()["cgal"]:
        conversion = measure_cgal_conversion(args.n)
        print(f"\nCGAL conversion of {args.n} points (s): "
              + ", ".join(f"{key}={value:.3f}" for key, value in conversion.items()))
    points = noisy_sphere(args.n, args.noise)
    print(f"\nnoisy sphere: n={args.n}, noise={args.noise}, mean |r-1| = "
          f"{_radial_error(points):.5f}\n")
    print("| peer | seconds | convert s | mean abs(r-1) | stages |")
    print("|---|---:|---:|---:|---|")
    for name, peer in PEERS.items():
        if args.only and not any(part in name for part in args.only):
            continue
        result = peer(points)
        stages = ", ".join(f"{key} {value:.2f}" for key, value in result.stage_seconds.items())
        print(f"| {name} | {result.seconds:.2f} | {result.convert_seconds:.3f} | "
              f"{_radial_error(result.points):.5f} | {stages} |", flush=True)
        if result.notes:
            print(f"|   note: {result.notes} | | | | |")


if __name__ == "__main__":
    main()
