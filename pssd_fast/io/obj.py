"""Wavefront OBJ files: the vertices are the points; every other line is kept as it was."""
import io
import dataclasses
from dataclasses import dataclass

import numpy as np

from ._common import PointCloudFileError, Source, decimal_strings

# Values a ``v`` line may hold after the keyword, and the fields beyond x y z they carry.
_VERTEX_FIELDS = {3: (), 4: ("w",), 6: ("red", "green", "blue")}
#: Fields an OBJ file can hold (on its ``v`` lines); others are not written.
FIELDS = ("w", "red", "green", "blue")


@dataclass(frozen=True, eq=False)
class _ObjSource(Source):
    lines: list  # every line of the file, verbatim
    v_lines: np.ndarray  # indices of the ``v`` lines
    vn_lines: np.ndarray  # indices of the ``vn`` lines

    def take(self, rows):
        if any(line.lstrip()[:2] in ("f ", "l ", "p ", "f\t", "l\t", "p\t")
               for line in self.lines):
            # Faces, lines and points elements index the vertices: dropping some would rewire them.
            raise PointCloudFileError(f"{self.path}: cannot drop vertices of an OBJ file with "
                                      "faces, lines or point elements (they index the vertices)")
        keep = np.zeros(len(self.v_lines), np.bool_)
        keep[rows] = True
        dropped = set(self.v_lines[~keep].tolist())
        if len(self.vn_lines) == len(self.v_lines):
            dropped |= set(self.vn_lines[~keep].tolist())
        lines = [line for i, line in enumerate(self.lines) if i not in dropped]
        return dataclasses.replace(self, lines=lines, v_lines=_keyword_lines(lines, "v"),
                                   vn_lines=_keyword_lines(lines, "vn"))


def _keyword_lines(lines, keyword):
    prefix = (keyword + " ", keyword + "\t")
    return np.array([i for i, line in enumerate(lines) if line.lstrip().startswith(prefix)],
                    dtype=np.int64)


def _parse(path, lines, indices, counts, what):
    """The numbers after the keyword of ``lines[indices]``, as an (m, k) float64 array."""
    rows = [lines[i].split("#", 1)[0] for i in indices]
    k = len(rows[0].split()) - 1
    if k not in counts:
        raise PointCloudFileError(f"{path}: line {indices[0] + 1}: a {what} line holds "
                                  f"{' or '.join(map(str, counts))} numbers; this one has {k}")
    try:
        return np.loadtxt(io.StringIO("\n".join(rows)), usecols=range(1, k + 1), ndmin=2)
    except ValueError:
        for i, row in zip(indices, rows, strict=True):
            tokens = row.split()[1:]
            try:
                [float(t) for t in tokens]
            except ValueError:
                ok = False
            else:
                ok = len(tokens) == k
            if not ok:
                raise PointCloudFileError(f"{path}: line {i + 1}: malformed {what} line "
                                          f"{row.strip()!r} (expected {k} numbers like the "
                                          f"first)") from None
        raise


def read(path, fh, ext):
    """Read the vertices of an OBJ file.

    Parameters
    ----------
    path : pathlib.Path or str
        The file's name, for messages.
    fh : binary file object
        The data.
    ext : str
        ``".obj"``.

    Returns
    -------
    points : (n, 3) numpy.ndarray
        The ``v`` lines' x y z, as float64.
    normals : (n, 3) numpy.ndarray or None
        The ``vn`` lines when there is one per vertex (as most exporters write them), else None.
    fields : dict of str to (n,) numpy.ndarray
        ``red green blue`` of ``v x y z r g b`` lines, or ``w`` of ``v x y z w`` lines.
    source : object
        Every line, for :func:`payload` to write back.

    Raises
    ------
    PointCloudFileError
        On a ``v`` or ``vn`` line with a bad number, or ``v`` lines of unequal length.
    """
    lines = fh.read().decode("utf-8", errors="surrogateescape").split("\n")
    v_lines, vn_lines = _keyword_lines(lines, "v"), _keyword_lines(lines, "vn")
    if len(v_lines) == 0:
        return np.empty((0, 3)), None, {}, None
    values = _parse(path, lines, v_lines, _VERTEX_FIELDS, "v")
    fields = {name: values[:, 3 + i].copy()
              for i, name in enumerate(_VERTEX_FIELDS[values.shape[1]])}
    normals = None
    if len(vn_lines) == len(v_lines):
        normals = _parse(path, lines, vn_lines, (3,), "vn")
    else:
        vn_lines = vn_lines[:0]  # per-corner normals: kept verbatim, not the points' normals
    return values[:, :3].copy(), normals, fields, _ObjSource(lines, v_lines, vn_lines)


def _rows(keyword, columns):
    strings = [decimal_strings(c) for c in columns]
    return [f"{keyword} " + " ".join(row) for row in zip(*strings, strict=True)]


def describe(source):
    """Lines naming what an OBJ file holds beyond its vertices: its faces, lines and point
    elements, with their counts."""
    counts = {}
    for line in source.lines:
        word = line.split(None, 1)[0] if line.strip() else ""
        if word in ("f", "l", "p"):
            counts[word] = counts.get(word, 0) + 1
    names = {"f": "faces", "l": "lines", "p": "point elements"}
    found = [f"{names[w]} ({counts[w]:,})" for w in ("f", "l", "p") if w in counts]
    return [f"other elements: {', '.join(found) if found else 'none'}"]


def _unit_colour(values):
    """Integer colours (8 bits, or 16 where a value exceeds 255) as floats in ``[0, 1]``."""
    if values.dtype.kind not in "iub":
        return values
    return values / (255.0 if values.max(initial=0) <= 255 else 65535.0)


def payload(path, ext, points, normals, fields, source):
    """Prepare an OBJ file: the source's lines with new ``v`` and ``vn`` lines.

    Parameters
    ----------
    path : pathlib.Path or str
        The output's name, for messages.
    ext : str
        ``".obj"``.
    points : (n, 3) numpy.ndarray
        Coordinates, written to the ``v`` lines in order.
    normals : (n, 3) numpy.ndarray or None
        Normals: they replace the source's ``vn`` lines when it has one per vertex, or follow
        the last ``v`` line when it has none; a source with per-corner ``vn`` lines keeps them.
    fields : dict of str to (n,) numpy.ndarray
        ``red green blue`` (written after x y z as 0-1 floats, the convention of MeshLab,
        Open3D and trimesh: integers divided by 255, or by 65535 where one exceeds 255;
        floats as they are) or ``w``; other fields cannot be stored and are ignored.
    source : object or None
        What :func:`read` returned for an OBJ input (faces, groups, materials, comments and
        every other line are kept), or None for a file of ``v`` (and ``vn``) lines.

    Returns
    -------
    callable
        Writes the file to the binary file object it is given.
    """
    rgb = ("red", "green", "blue")
    if all(c in fields for c in rgb):
        extra = [_unit_colour(fields[c]) for c in rgb]
    else:
        extra = [fields["w"]] if "w" in fields else []
    v_rows = _rows("v", [*points.T, *extra])
    vn_rows = _rows("vn", normals.T) if normals is not None else []
    if source is None:
        lines = v_rows + vn_rows + [""]
    else:
        lines = list(source.lines)
        for i, row in zip(source.v_lines, v_rows, strict=True):
            lines[i] = row
        if vn_rows and len(source.vn_lines):
            for i, row in zip(source.vn_lines, vn_rows, strict=True):
                lines[i] = row
        elif vn_rows and not any(line.lstrip().startswith(("vn ", "vn\t")) for line in lines):
            last = source.v_lines[-1]
            lines[last + 1:last + 1] = vn_rows

    def write(fh):
        fh.write("\n".join(lines).encode("utf-8", "surrogateescape"))
    return write
