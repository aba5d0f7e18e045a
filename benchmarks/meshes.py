"""Triangle meshes for tests and benchmarks: reading, sampling, sharp edges, edge distances.

The reference models (Igea, Fandisk, the dragon) are not shipped with the package; they live in
the ``meshes/`` folder of a data folder the caller names, through the ``PSSD_DATA`` environment
variable or the ``path`` of :func:`data_dir`. Everything here is plain numpy, so it can be used
without compiling any kernel.
"""
import gzip
import itertools
import numbers
import os
import re
from pathlib import Path

import numpy as np

from pssd_fast._validation import check_int, seeded_rng

__all__ = [
    "KINDS",
    "data_dir",
    "data_path",
    "normalize_to_unit_diagonal",
    "read_feat",
    "read_obj",
    "read_off",
    "sample_surface",
    "segment_distance",
    "sharp_edges",
]

_HEAD = re.compile(r"^[^\S\n]*(\S*)", re.M)
_COMMENT = re.compile(r"#[^\n]*")
_SLASH = re.compile(r"/\S*")

# Size of one (chunk, k) float64 scratch array in segment_distance: about L2-cache sized, which
# measured faster than both smaller chunks (more Python overhead) and larger ones (memory bound).
_SCRATCH_BYTES = 2**20


#: The folders of a data folder, one per kind of data: the paper's meshes, LiDAR files, raw range
#: scans and the PU-Net test meshes.
KINDS = ("meshes", "lidar", "realscans", "punet")


def data_path(root, kind="meshes"):
    """Where the data of ``kind`` is under the data folder ``root``, whether or not it exists.

    Parameters
    ----------
    root : str or os.PathLike
        A data folder, holding one folder per kind (``meshes/``, ``lidar/``, ``realscans/``,
        ``punet/``); or, as ``PSSD_DATA`` was once set, the meshes folder itself.
    kind : str, default "meshes"
        One of :data:`KINDS`.

    Returns
    -------
    pathlib.Path
        ``root/kind``. When ``root`` is a folder holding files but none of the kinds' folders,
        it is read as the meshes folder itself: ``root`` for the meshes, ``root/../kind`` for
        the others.

    Raises
    ------
    ValueError
        If ``kind`` is not one of :data:`KINDS`.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown kind of data {kind!r}; choose one of {', '.join(KINDS)}")
    root = Path(root).expanduser()
    if (root.is_dir() and not any((root / k).is_dir() for k in KINDS)
            and any(p.is_file() for p in root.iterdir())):
        return root if kind == "meshes" else root.parent / kind
    return root / kind


def data_dir(path=None, kind="meshes"):
    """Folder holding the data of ``kind``, or None if none is given or it does not exist.

    Parameters
    ----------
    path : str or os.PathLike, optional
        The data folder (see :func:`data_path`). When omitted, the ``PSSD_DATA`` environment
        variable names it.
    kind : str, default "meshes"
        One of :data:`KINDS`.

    Returns
    -------
    pathlib.Path or None
        The folder of ``kind`` under ``path`` if given, else under ``$PSSD_DATA`` if that
        variable is set and not empty; None when neither is given or that folder does not
        exist.

    Notes
    -----
    The data is not part of the package, and the package never guesses where it is: there
    is no default location. An explicit ``path`` or ``PSSD_DATA`` that points nowhere gives None
    rather than another copy of the data, so a typo is not silently masked. Tools that keep the
    data in a known place (the project's tests and benchmarks) pass that place as ``path``.
    """
    if path is None:
        path = os.environ.get("PSSD_DATA") or None
    if path is None:
        return None
    folder = data_path(path, kind)
    return folder if folder.is_dir() else None


def _read_text(path):
    """Whole text of ``path``, transparently gunzipped when the name ends in ``.gz``."""
    path = Path(path)
    opener = gzip.open if path.name.endswith(".gz") else open
    with opener(path, "rt", encoding="utf-8") as fh:
        return fh.read()


def _load_rows(rows, linenos, n_values, dtype, path, what):
    """Parse ``n_values`` numbers after the keyword of every row, as an (m, n_values) array.

    ``np.loadtxt`` does the parsing (C speed). When it rejects the input, the offending row is
    found by bisecting with the same parser, so the reported line is exactly one it refuses.
    """
    def load(part):
        return np.loadtxt(part, dtype=dtype, usecols=range(1, n_values + 1), comments=None,
                          ndmin=2)

    try:
        return load(rows)
    except ValueError as exc:
        lo, hi = 0, len(rows)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            try:
                load(rows[lo:mid])
            except ValueError:
                hi = mid
            else:
                lo = mid
        raise ValueError(f"{path}:{linenos[lo]}: malformed {what} line {rows[lo].strip()!r} "
                         f"(expected {n_values} numbers after the keyword)") from exc


def _token_counts(lines):
    """Number of whitespace-separated tokens on each line, counted over the raw bytes at once."""
    buf = np.frombuffer("\n".join(lines).encode(), dtype=np.uint8)
    in_token = buf > ord(" ")
    token_start = in_token & ~np.r_[False, in_token[:-1]]
    line_of = np.searchsorted(np.flatnonzero(buf == ord("\n")), np.flatnonzero(token_start))
    return np.bincount(line_of, minlength=len(lines))


def read_obj(path):
    """Read the vertices and faces of a Wavefront OBJ file.

    Parameters
    ----------
    path : str or os.PathLike
        The file; read through gzip when its name ends in ``.gz``.

    Returns
    -------
    vertices : (V, 3) float64
        The ``x y z`` of every ``v`` line, in file order (a 4th ``w`` or colour values are
        ignored).
    faces : (F, 3) int64
        0-based vertex indices of the triangles, in file order. Polygons with more than three
        corners are fan-triangulated around their first corner.

    Raises
    ------
    ValueError
        On a malformed ``v`` or ``f`` line (too few entries, unparsable or non-finite number,
        index 0 or out of range); the message names the file and the 1-based line number.
    OSError
        If the file cannot be read.

    Notes
    -----
    Face entries may be ``a``, ``a/b``, ``a/b/c`` or ``a//c``; only ``a`` is used. Indices are
    1-based; a negative index counts back from the vertices defined before its line (``-1`` is
    the most recent one), as the OBJ specification says. ``#`` starts a comment anywhere on a
    line, and every line type other than ``v`` and ``f`` (``vt``, ``vn``, ``g``, ``usemtl``,
    ...) is ignored. Parsing is vectorised (``np.loadtxt`` per group of same-length lines), so
    the 134k-vertex Igea scan takes well under a second.
    """
    text = _read_text(path)
    if "#" in text:
        text = _COMMENT.sub("", text)
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    lines = text.split("\n")
    heads = _HEAD.findall(text)  # first token of every line, aligned with ``lines``
    is_v = np.array([head == "v" for head in heads], dtype=bool)
    f_at = np.flatnonzero([head == "f" for head in heads])

    v_at = np.flatnonzero(is_v)
    vertices = np.empty((0, 3))
    if v_at.size:
        vertices = _load_rows([lines[i] for i in v_at], v_at + 1, 3, np.float64, path, "vertex")
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
        if bad.size:
            raise ValueError(f"{path}:{v_at[bad[0]] + 1}: non-finite vertex coordinate")

    faces = np.empty((0, 3), dtype=np.int64)
    if f_at.size:
        f_lines = [lines[i] for i in f_at]
        if "/" in text:
            # Keep the vertex index of every a/b/c, a//c or a/b entry.
            f_lines = _SLASH.sub("", "\n".join(f_lines)).split("\n")
        sizes = _token_counts(f_lines) - 1
        short = np.flatnonzero(sizes < 3)
        if short.size:
            raise ValueError(f"{path}:{f_at[short[0]] + 1}: face needs at least 3 vertices")
        n_before = np.cumsum(is_v)[f_at]  # vertices defined above each face line
        tris, keys = [], []
        for size in np.unique(sizes):
            sel = np.flatnonzero(sizes == size)
            corners = _load_rows([f_lines[i] for i in sel], f_at[sel] + 1, size, np.int64,
                                 path, "face")
            idx = np.where(corners > 0, corners - 1, corners + n_before[sel, None])
            bad = np.flatnonzero(((corners == 0) | (idx < 0) | (idx >= len(vertices))).any(1))
            if bad.size:
                raise ValueError(f"{path}:{f_at[sel[bad[0]]] + 1}: face index out of range "
                                 f"({len(vertices)} vertices in the file, "
                                 f"{n_before[sel[bad[0]]]} above this line)")
            fan = np.arange(1, size - 1)
            tris.append(np.stack([np.broadcast_to(idx[:, :1], (len(idx), size - 2)),
                                  idx[:, fan], idx[:, fan + 1]], axis=2).reshape(-1, 3))
            keys.append(np.repeat(sel, size - 2))
        # Restore file order across the groups of different polygon sizes.
        faces = np.concatenate(tris)[np.argsort(np.concatenate(keys), kind="stable")]
    return vertices, faces


def read_off(path):
    """Read the vertices and faces of an OFF file (the PU-Net test meshes).

    Parameters
    ----------
    path : str or os.PathLike
        As in :func:`read_obj`.

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        0-based vertex indices; polygons of more than three corners are fan-triangulated
        around their first corner.

    Raises
    ------
    ValueError
        The file does not start with ``OFF``, holds fewer numbers than its counts need, a
        non-finite coordinate, or a face index out of range; the message names the file.
    """
    text = _COMMENT.sub("", _read_text(path))
    tokens = text.split()
    if not tokens or tokens[0] != "OFF":
        raise ValueError(f"{path}: not an OFF file (it does not start with 'OFF')")
    try:
        n_vertices, n_faces = int(tokens[1]), int(tokens[2])
        values = np.array(tokens[4:4 + 3 * n_vertices], dtype=np.float64)
        rest = np.array(tokens[4 + 3 * n_vertices:], dtype=np.int64)
    except (IndexError, ValueError) as exc:
        raise ValueError(f"{path}: malformed OFF header or body ({exc})") from None
    if values.shape[0] != 3 * n_vertices:
        raise ValueError(f"{path}: {n_vertices} vertices announced, "
                         f"{values.shape[0] // 3} found")
    vertices = values.reshape(n_vertices, 3)
    if not np.isfinite(vertices).all():
        raise ValueError(f"{path}: non-finite vertex coordinate")
    tris, at = [], 0
    for _ in range(n_faces):
        if at >= rest.shape[0] or at + 1 + rest[at] > rest.shape[0] or rest[at] < 3:
            raise ValueError(f"{path}: {n_faces} faces announced, the file ends or breaks "
                             f"after {len(tris)}")
        corners = rest[at + 1:at + 1 + rest[at]]
        tris += [(corners[0], corners[i], corners[i + 1]) for i in range(1, len(corners) - 1)]
        at += 1 + rest[at]
    faces = np.array(tris, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        raise ValueError(f"{path}: face index out of range ({n_vertices} vertices)")
    return vertices, faces


def read_feat(path):
    """Read the feature polylines of ``path``, a ``.feat`` file (the format of
    ``fandisk.feat``; gzipped where its name ends in ``.gz``, as :func:`read_obj` reads).

    Returns
    -------
    list of (m_i, 3) float64
        One array of points per polyline, in file order.

    Raises
    ------
    ValueError
        If the header is not ``feat <count>``, a point count is not a non-negative integer, a
        point line does not hold exactly three numbers, the file ends early or has data after
        the last polyline; the message names the 1-based line number.
    OSError
        If the file cannot be read.

    Notes
    -----
    The format: a first line ``feat N``, then ``N`` polylines, each a line holding its point
    count ``m`` followed by ``m`` lines of ``x y z``. Blank lines are skipped.
    """
    rows = [(lineno, line.split())
            for lineno, line in enumerate(_read_text(path).splitlines(), start=1)
            if line.strip()]
    if not rows:
        raise ValueError(f"{path}: empty feat file")
    rows = iter(rows)

    def numbers_on(row, kind, count):
        """The ``count`` numbers of type ``kind`` on ``row``, else a ValueError naming its line."""
        lineno, parts = row
        try:
            if len(parts) == count:
                return [kind(part) for part in parts]
        except ValueError:
            pass
        raise ValueError(f"{path}:{lineno}: expected {count} {kind.__name__} value(s), got "
                         f"{' '.join(parts)!r}")

    lineno, parts = next(rows)
    if len(parts) != 2 or parts[0] != "feat":
        raise ValueError(f"{path}:{lineno}: expected header 'feat <count>', "
                         f"got {' '.join(parts)!r}")
    (n_lines,) = numbers_on((lineno, parts[1:]), int, 1)
    if n_lines < 0:
        raise ValueError(f"{path}:{lineno}: negative polyline count {n_lines}")
    polylines = []
    for row in rows:
        if len(polylines) == n_lines:
            raise ValueError(f"{path}:{row[0]}: unexpected data after the last polyline")
        (m,) = numbers_on(row, int, 1)
        if m < 0:
            raise ValueError(f"{path}:{row[0]}: negative point count {m}")
        points = [numbers_on(point_row, float, 3) for point_row in itertools.islice(rows, m)]
        if len(points) < m:
            raise ValueError(f"{path}:{row[0]}: polyline of {m} points is cut short")
        polylines.append(np.array(points, dtype=np.float64).reshape(m, 3))
    if len(polylines) < n_lines:
        raise ValueError(f"{path}: file ends after {len(polylines)} of {n_lines} polylines")
    return polylines


def _as_points(array, name, allow_empty=True):
    """``array`` as a finite (n, 3) float64 array, else a ValueError naming ``name``."""
    out = np.asarray(array, dtype=np.float64)
    if out.ndim != 2 or out.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {out.shape}")
    if not allow_empty and out.shape[0] == 0:
        raise ValueError(f"{name} must not be empty")
    if not np.isfinite(out).all():
        raise ValueError(f"{name} contains non-finite values")
    return out


def _as_faces(faces, n_vertices):
    """``faces`` as a non-empty (F, 3) int64 array indexing ``n_vertices`` vertices."""
    out = np.asarray(faces)
    if out.ndim != 2 or out.shape[1] != 3:
        raise ValueError(f"faces must have shape (F, 3), got {out.shape}")
    if out.shape[0] == 0:
        raise ValueError("faces must not be empty")
    if not np.issubdtype(out.dtype, np.integer):
        raise TypeError(f"faces must be an integer array, got dtype {out.dtype}")
    if out.min() < 0 or out.max() >= n_vertices:
        raise ValueError(f"faces index vertices in [{out.min()}, {out.max()}] but there are "
                         f"{n_vertices} vertices")
    return out.astype(np.int64, copy=False)


def _face_cross(vertices, faces):
    """Cross product of the two edges leaving each face's first corner, (F, 3)."""
    a = vertices[faces[:, 0]]
    return np.cross(vertices[faces[:, 1]] - a, vertices[faces[:, 2]] - a)


def sample_surface(vertices, faces, n_points, seed=0):
    """Sample points uniformly by area on a triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Vertex positions.
    faces : (F, 3) array_like of int
        0-based vertex indices of each triangle; the winding defines the normal direction.
    n_points : int
        Number of points, at least 1.
    seed : int, optional
        Seed of ``np.random.default_rng``; the same arguments give bit-identical output.

    Returns
    -------
    points : (n_points, 3) float64
        The samples, in random order.
    face_index : (n_points,) int64
        Face each sample lies on.
    normals : (n_points, 3) float64
        Unit normal of that face, oriented by its winding (counter-clockwise seen from the
        side the normal points to).

    Raises
    ------
    TypeError
        If ``n_points`` or ``seed`` is not an integer, or ``faces`` is not integer-typed.
    ValueError
        If ``n_points < 1``, ``seed < 0``, the arrays have the wrong shape, ``vertices`` is not
        finite, a face index is out of range, or the mesh has zero total area.

    Notes
    -----
    Per-face counts are one multinomial draw with probabilities proportional to the face areas
    (degenerate faces get none), and within a triangle ``(a, b, c)`` a point is
    ``(1 - sqrt(r1)) a + sqrt(r1) (1 - r2) b + sqrt(r1) r2 c`` with ``r1, r2 ~ U[0, 1)``, which
    is uniform over the triangle. The samples are then shuffled so that their order says nothing
    about the face they came from.
    """
    n_points = check_int(n_points, "n_points", minimum=1)
    rng = seeded_rng(seed)
    vertices = _as_points(vertices, "vertices", allow_empty=False)
    faces = _as_faces(faces, len(vertices))

    cross = _face_cross(vertices, faces)
    double_area = np.linalg.norm(cross, axis=1)
    total = double_area.sum()
    if not total > 0:
        raise ValueError("the mesh has zero total area")
    counts = rng.multinomial(n_points, double_area / total)
    face_index = np.repeat(np.arange(len(faces), dtype=np.int64), counts)
    face_index = face_index[rng.permutation(n_points)]

    r = rng.random((n_points, 2))
    s = np.sqrt(r[:, :1])
    tri = faces[face_index]
    points = ((1.0 - s) * vertices[tri[:, 0]] + s * (1.0 - r[:, 1:]) * vertices[tri[:, 1]]
              + s * r[:, 1:] * vertices[tri[:, 2]])
    normals = cross[face_index] / double_area[face_index, None]
    return points, face_index, normals


def sharp_edges(vertices, faces, angle_deg=30.0):
    """Edges where the surface bends by more than ``angle_deg``.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Vertex positions.
    faces : (F, 3) array_like of int
        0-based, consistently wound triangles.
    angle_deg : float, optional
        Threshold, in degrees, on the angle between the normals of the two faces sharing an
        edge (0 for a flat continuation, 90 for a cube edge), in ``[0, 180]``.

    Returns
    -------
    (E, 2) int64
        The sharp edges as vertex index pairs ``(i, j)`` with ``i < j``, sorted
        lexicographically, each listed once.

    Raises
    ------
    TypeError
        If ``faces`` is not integer-typed or ``angle_deg`` is not a real number.
    ValueError
        If the arrays have the wrong shape, ``vertices`` is not finite, a face index is out of
        range, or ``angle_deg`` is outside ``[0, 180]``.

    Notes
    -----
    Only edges shared by exactly two faces are considered: boundary edges (one face) and
    non-manifold edges (three or more) are never reported. An edge next to a zero-area face has
    no defined angle and is not reported either. Normals come from the winding, so an
    inconsistently wound neighbour makes its edge look sharp (angle near 180 degrees).
    """
    if isinstance(angle_deg, bool) or not isinstance(angle_deg, numbers.Real):
        raise TypeError(f"angle_deg must be a real number, got {angle_deg!r}")
    if not 0.0 <= angle_deg <= 180.0:
        raise ValueError(f"angle_deg must be in [0, 180], got {angle_deg}")
    vertices = _as_points(vertices, "vertices", allow_empty=False)
    faces = _as_faces(faces, len(vertices))

    with np.errstate(invalid="ignore", divide="ignore"):
        cross = _face_cross(vertices, faces)
        normals = cross / np.linalg.norm(cross, axis=1, keepdims=True)

    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(faces)), 3)
    # One integer key per undirected edge; sorting it groups the faces of each edge together.
    key = edges[:, 0] * len(vertices) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    key = key[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    sizes = np.diff(np.r_[starts, len(key)])
    pairs = starts[sizes == 2]
    f0 = owner[order[pairs]]
    f1 = owner[order[pairs + 1]]
    # A NaN normal (zero-area face) compares False: its edges are never reported.
    cos_angle = np.einsum("ij,ij->i", normals[f0], normals[f1])
    sharp = cos_angle < np.cos(np.radians(angle_deg))
    return edges[order[pairs[sharp]]]


def segment_distance(points, a, b):
    """Exact Euclidean distance from each point to the nearest of a set of segments.

    Parameters
    ----------
    points : (n, 3) array_like of float
        Query points.
    a, b : (k, 3) array_like of float
        Segment ``i`` runs from ``a[i]`` to ``b[i]``; ``k >= 1``. Zero-length segments
        (``a[i] == b[i]``) are points.

    Returns
    -------
    (n,) float64
        ``min_i dist(points[j], [a[i], b[i]])`` for every query point ``j``.

    Raises
    ------
    ValueError
        If an array has the wrong shape, ``a`` and ``b`` differ in shape, there are no
        segments, or an input is not finite.

    Notes
    -----
    Brute force over all point/segment pairs, with the points taken in chunks so that the
    scratch arrays stay small (cache-sized) whatever ``k`` is. Each pair is evaluated from the
    difference vectors themselves (no ``|p|^2 - 2 p.a + |a|^2`` expansion), so the result has
    no cancellation error for points close to a segment.
    """
    points = _as_points(points, "points")
    a = _as_points(a, "a", allow_empty=False)
    b = _as_points(b, "b", allow_empty=False)
    if a.shape != b.shape:
        raise ValueError(f"a and b must have the same shape, got {a.shape} and {b.shape}")

    d = b - a
    len2 = np.einsum("ij,ij->i", d, d)
    # Zero-length segments: any finite inverse works since the projection parameter is clipped
    # and multiplies a zero direction.
    inv_len2 = np.divide(1.0, len2, out=np.zeros_like(len2), where=len2 > 0)
    ax, ay, az = a.T
    dx, dy, dz = d.T
    out = np.empty(len(points))
    chunk = max(1, _SCRATCH_BYTES // (8 * len(a)))
    for start in range(0, len(points), chunk):
        p = points[start:start + chunk]
        ex = p[:, 0:1] - ax
        ey = p[:, 1:2] - ay
        ez = p[:, 2:3] - az
        t = ex * dx
        t += ey * dy
        t += ez * dz
        t *= inv_len2
        np.clip(t, 0.0, 1.0, out=t)
        # (e - t d) componentwise, squared and summed in place to keep only four live arrays.
        ex -= t * dx
        ey -= t * dy
        ez -= t * dz
        ex *= ex
        ey *= ey
        ez *= ez
        ex += ey
        ex += ez
        out[start:start + chunk] = ex.min(axis=1)
    return np.sqrt(out)


def normalize_to_unit_diagonal(vertices):
    """Centre vertices on their bounding-box centre and scale the box diagonal to 1.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Vertex (or point) positions, ``V >= 1``.

    Returns
    -------
    vertices_scaled : (V, 3) float64
        ``(vertices - offset) * scale``.
    scale : float
        ``1 / diagonal`` of the input bounding box.
    offset : (3,) float64
        The input bounding-box centre; ``vertices == vertices_scaled / scale + offset``.

    Raises
    ------
    ValueError
        If ``vertices`` has the wrong shape, is empty or not finite, or all vertices coincide
        (zero diagonal).
    """
    vertices = _as_points(vertices, "vertices", allow_empty=False)
    lo = vertices.min(axis=0)
    hi = vertices.max(axis=0)
    diagonal = float(np.linalg.norm(hi - lo))
    if not diagonal > 0:
        raise ValueError("all vertices coincide: the bounding-box diagonal is 0")
    offset = 0.5 * (lo + hi)
    scale = 1.0 / diagonal
    return (vertices - offset) * scale, scale, offset
