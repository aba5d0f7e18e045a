"""Whitespace-separated text columns (``.xyz``, ``.pts``, ``.txt``), with plain numpy."""
import io
import os
from dataclasses import dataclass

import numpy as np

from ._common import COORDS, NORMALS, PointCloudFileError, Source

TEXT_CHUNK = 2**16  # rows formatted at once when writing text


@dataclass(frozen=True)
class _TextSource(Source):
    comments: tuple  # leading comment lines, verbatim, without the column-name line


def _default_names(ncols):
    """Column names a reader infers for a text file without a column-name comment."""
    if ncols == 6:
        return [*COORDS, *NORMALS]
    return [*COORDS, *(f"col{i}" for i in range(3, ncols))]


def _text_parse_error(path, text, start, first_line, ncols, exc):
    """Find the first line numpy refused (slow, only after a failure) and describe it."""
    for offset, line in enumerate(text[start:].split("\n")):
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        if len(tokens) != ncols:
            return PointCloudFileError(f"{path}: line {first_line + offset} has {len(tokens)} "
                                       f"columns; the first data line has {ncols}")
        for token in tokens:
            try:
                float(token)
            except ValueError:
                return PointCloudFileError(f"{path}: bad number {token!r} on line "
                                           f"{first_line + offset}")
    return PointCloudFileError(f"{path}: {' '.join(str(exc).split())}")


def read(path):
    """Read a text file of whitespace-separated columns.

    Parameters
    ----------
    path : pathlib.Path
        An existing ``.xyz``, ``.pts`` or ``.txt`` file.

    Returns
    -------
    points : (n, 3) numpy.ndarray
        The first three columns, as float64 (empty if the file has no data lines).
    normals : (n, 3) numpy.ndarray or None
        The ``nx ny nz`` columns (columns 4-6 of a six-column file without names), or None.
    fields : dict of str to (n,) numpy.ndarray
        Every other column, as float64, named by the column-name comment or ``col3``...
    source : object or None
        The leading comment lines, for :func:`payload` to write back; None without data.

    Raises
    ------
    PointCloudFileError
        On fewer than three columns, rows of unequal length, a bad number, or a point-count
        line that does not match the rows (or that claims more than the file can hold).

    Notes
    -----
    ``#`` starts a comment. A first line holding a single integer is a point count (as in PTS
    files). The last comment line before the data names the columns when it lists as many
    distinct names as there are columns, starting with ``x y z``.
    """
    # Undecodable bytes are kept as surrogates so that comments are written back verbatim.
    with open(path, encoding="utf-8", errors="surrogateescape") as fh:
        text = fh.read()
    comments, count, pos, lineno = [], None, 0, 1
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        line = text[pos:end]
        tokens = line.split("#", 1)[0].split()
        if tokens:
            if count is not None or len(tokens) != 1 or not tokens[0].isdigit():
                break
            count = int(tokens[0])  # a PTS point-count line, before any data
        elif line.strip():
            comments.append(line)
        pos, lineno = end + 1, lineno + 1
    if pos >= len(text):
        if count:
            raise PointCloudFileError(f"{path}: first line says {count:,} points but the file "
                                      f"holds none")
        return np.empty((0, 3)), None, {}, None
    ncols = len(tokens)
    if ncols < 3:
        raise PointCloudFileError(f"{path}: line {lineno} has {ncols} columns; x y z need 3")
    # Each row takes at least two characters per value: refuse absurd counts before parsing.
    if count is not None and count * 2 * ncols > len(text) - pos + 1:
        raise PointCloudFileError(f"{path}: first line says {count:,} points, more than the "
                                  f"{len(text) - pos:,} characters after it can hold")
    try:
        data = np.loadtxt(io.StringIO(text[pos:]), dtype=np.float64, comments="#", ndmin=2)
    except ValueError as exc:
        raise _text_parse_error(path, text, pos, lineno, ncols, exc) from None
    if count is not None and count != len(data):
        raise PointCloudFileError(f"{path}: first line says {count:,} points but the file holds "
                                  f"{len(data):,}")
    names = _default_names(ncols)
    if comments:
        named = comments[-1].split("#", 1)[-1].split()
        if len(named) == ncols and named[:3] == list(COORDS) and len(set(named)) == ncols:
            names = named
            comments.pop()
    column = {name: data[:, i] for i, name in enumerate(names)}
    normals = None
    if all(c in column for c in NORMALS):
        normals = np.column_stack([column[c] for c in NORMALS])
    fields = {name: np.ascontiguousarray(col) for name, col in column.items()
              if name not in COORDS + NORMALS}
    source = _TextSource(os.path.abspath(path), tuple(comments))
    return data[:, :3].copy(), normals, fields, source


def _text_column(values):
    """Decimal strings of ``values``: numpy prints the shortest string that reads back equal."""
    if values.dtype.kind == "b":
        values = values.astype(np.uint8)
    return values.astype(str).tolist()


def payload(path, points, normals, fields, source):
    """Prepare a text file: a column-name comment line, then one row per point.

    Parameters
    ----------
    path : pathlib.Path
        The output file; a ``.pts`` one gets the point count line before the rows, and the
        column-name line only when the names differ from what a reader infers by default.
    points : (n, 3) numpy.ndarray
        Coordinates, the first three columns.
    normals : (n, 3) numpy.ndarray or None
        Normals, the ``nx ny nz`` columns after them.
    fields : dict of str to (n,) numpy.ndarray
        Further columns, each value in the shortest decimal form that reads back equal in
        its own dtype (bool as 0 and 1).
    source : object or None
        What :func:`read` returned for a text input, whose leading comment lines are written
        first, or None.

    Returns
    -------
    callable
        Writes the file to the binary file object it is given, in chunks of rows.
    """
    pts = path.suffix.lower() == ".pts"
    names, columns = list(COORDS), [points[:, 0], points[:, 1], points[:, 2]]
    if normals is not None:
        names += NORMALS
        columns += [normals[:, 0], normals[:, 1], normals[:, 2]]
    names += fields
    columns += fields.values()
    head = list(source.comments) if source is not None else []
    # PTS readers expect the count first; they get a column line only when they need one.
    if not pts or names != _default_names(len(names)):
        head.append("# " + " ".join(names))
    if pts:
        head.append(str(len(points)))

    def write(fh):
        fh.write("".join(line + "\n" for line in head).encode("utf-8", "surrogateescape"))
        for start in range(0, len(points), TEXT_CHUNK):
            rows = zip(*(_text_column(c[start:start + TEXT_CHUNK]) for c in columns),
                       strict=True)
            fh.write("".join(" ".join(row) + "\n" for row in rows).encode("ascii"))
    return write
