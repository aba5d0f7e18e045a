"""Text columns (``.xyz``, ``.pts``, ``.txt``, ``.csv``), with plain numpy.

Columns are separated by commas, semicolons, tabs or spaces (detected from the first data
line); lines before the data may be comments (``#`` or ``//``), a PTS point-count line and a
column-name line (``//X,Y,Z,R,G,B``, ``x y z``, ``# x y z nx ny nz``).
"""
import io
import warnings
from dataclasses import dataclass

import numpy as np

from ._columns import canonical, integer_type
from ._common import (COORDS, NORMALS, PointCloudFileError, PointCloudWarning, Source,
                      decimal_strings)

TEXT_CHUNK = 2**16  # rows formatted at once when writing text
#: How far from 1 the length of every row of columns 4-6 of an unnamed six-column file may be
#: for them to be read as normals (rows of NaN or zeros, no normal, aside).
UNIT_TOLERANCE = 0.05
_PTS_FIRST = ("intensity", "red", "green", "blue")  # the Leica PTS columns after x y z
_COLOURS = ("red", "green", "blue")
_COMMENT = ("#", "//")


@dataclass(frozen=True)
class _TextSource(Source):
    comments: tuple  # leading comment lines, verbatim, without the column-name line


def _default_names(ncols, ext):
    """Column names a reader gives a text file without a column-name line, before
    :func:`_six_columns` looks at the values of a six-column one."""
    if ext == ".pts" and ncols in (4, 7):
        return [*COORDS, *_PTS_FIRST[:ncols - 3]]
    return [*COORDS, *(f"col{i}" for i in range(3, ncols))]


def _six_columns(path, data, ints):
    """The names of an unnamed six-column file, from columns 4-6 (``ints``: those written as
    integers, :func:`_integer_columns`): colours when all three are integers from 0 to 65535,
    else normals when every row has length 1 (within ``UNIT_TOLERANCE``) or is NaN or zeros
    (no normal), else fields ``col3`` to ``col5``. A note says which (docs/DECISIONS.md,
    "Unnamed text columns")."""
    rest = data[:, 3:6]
    length = np.linalg.norm(rest, axis=1)
    if all(i in ints and ints[i].min() >= 0 and ints[i].max() <= 65535 for i in (3, 4, 5)):
        names, why = list(_COLOURS), "integers"
    elif np.all(np.isnan(rest).all(axis=1) | (length == 0.0)
                | (np.abs(length - 1.0) <= UNIT_TOLERANCE)):
        names, why = list(NORMALS), "unit vectors"
        for i in (3, 4, 5):
            ints.pop(i, None)
    else:
        names, why = ["col3", "col4", "col5"], "neither integer colours nor unit normals"
    warnings.warn(f"{path}: no column names; columns 4-6 read as {', '.join(names)} ({why}); "
                  f"name the columns to read them otherwise (columns=, --columns)",
                  PointCloudWarning, stacklevel=4)
    return [*COORDS, *names]


def _separator(line):
    """The column separator of a data line: ``;``, ``,`` or None (tabs and spaces)."""
    return next((sep for sep in ";," if sep in line), None)


def _split(line, sep):
    """The tokens of ``line``, each without the double quotes around it (``"1.5"``); a
    separator ending it (``1,2,3,``) opens no column."""
    tokens = line.split() if not sep else [t.strip() for t in line.split(sep)]
    if sep and len(tokens) > 1 and not tokens[-1]:
        tokens = tokens[:-1]
    return [t[1:-1].strip() if len(t) > 1 and t[0] == t[-1] == '"' else t for t in tokens]


def _decimal_comma(content, sep):
    """Whether a data line separated by ``;`` writes its numbers with decimal commas
    (``1,5;2,25;3``), as spreadsheets do where the comma is the decimal mark."""
    return sep == ";" and "," in content and all(
        _is_number(t.replace(",", ".", 1)) for t in _split(content, sep))


def _is_number(token):
    try:
        float(token)
    except ValueError:
        return False
    return True


def _column_names(path, line, lineno, sep, ncols, bare):
    """Canonical names from a column-name line, or None when a comment line is not one.

    A bare line (no ``#`` or ``//``) before the data can only be a column-name line, so it is
    refused when it does not fit; a comment line that does not fit is just a comment.
    """
    text = line.strip()
    for mark in _COMMENT:
        text = text.removeprefix(mark)
    tokens = _split(text, sep if sep and sep in text else None)
    names = [canonical(t) for t in tokens]
    problem = _names_problem(tokens, names, ncols)
    if problem is None:
        return names
    if bare:
        raise PointCloudFileError(f"{path}: header line {lineno} {problem}: {line.strip()!r}")
    return None


def _names_problem(tokens, names, ncols):
    """What keeps ``names`` (canonical ``tokens``) from naming ``ncols`` columns, or None."""
    if len(names) != ncols:
        return f"names {len(names)} columns but the data has {ncols}"
    if not all(names):
        return f"leaves column {names.index('') + 1} without a name"
    if any(_is_number(t) for t in tokens):
        return "mixes names and numbers"
    if not set(COORDS) <= set(names):
        return "names no x, y and z columns"
    if len(set(names)) != ncols:
        twice = sorted({n for n in names if names.count(n) > 1})
        return f"names columns {twice} more than once"
    return None


def _given_names(path, columns, ncols, header):
    """Canonical names of the ``columns`` the caller gives, which replace the ``header``
    line's (if any; with a note where they differ)."""
    tokens = [t.strip() for t in columns]
    names = [canonical(t) for t in tokens]
    problem = _names_problem(tokens, names, ncols)
    if problem is not None:
        raise PointCloudFileError(f"{path}: the column list {','.join(tokens)} {problem}")
    if header is not None and header[1] != names:
        warnings.warn(f"{path}: the column names given ({', '.join(names)}) replace those of "
                      f"header line {header[0]} ({', '.join(header[1])})", PointCloudWarning,
                      stacklevel=4)
    return names


def _text_parse_error(path, text, start, first_line, ncols, sep, comma, exc):
    """Find the first line numpy refused (slow, only after a failure) and describe it
    (``comma``: the numbers are written with decimal commas)."""
    for offset, line in enumerate(text[start:].split("\n")):
        content = line.split("#", 1)[0]
        if not content.strip():
            continue
        tokens = _split(content, sep)
        if len(tokens) != ncols:
            return PointCloudFileError(f"{path}: line {first_line + offset} has {len(tokens)} "
                                       f"columns; the first data line has {ncols}")
        for token in tokens:
            if not _is_number(token.replace(",", ".", 1) if comma else token):
                return PointCloudFileError(f"{path}: bad number {token!r} on line "
                                           f"{first_line + offset}")
    return PointCloudFileError(f"{path}: {' '.join(str(exc).split())}")


def _integer_columns(data, body, sep, names):
    """Indices and int64 values of the field columns written as integers.

    Columns whose values are all whole numbers are parsed again as int64, which refuses
    ``6.0``: a float column that happens to hold whole numbers stays float.
    """
    candidates = [i for i, name in enumerate(names) if name not in COORDS + NORMALS
                  and np.all(np.abs(data[:, i]) <= 2.0**53)
                  and np.array_equal(data[:, i], np.round(data[:, i]))]

    def parse(cols):
        return np.loadtxt(io.StringIO(body), dtype=np.int64, delimiter=sep, comments="#",
                          usecols=cols, ndmin=2, quotechar='"')

    if not candidates:
        return {}
    try:
        return dict(zip(candidates, parse(candidates).T, strict=True))
    except ValueError:
        found = {}
        for i in candidates:
            try:
                found[i] = parse([i])[:, 0]
            except ValueError:
                pass
        return found


def read(path, fh, ext, columns=None):
    """Read a text file of separated columns.

    Parameters
    ----------
    path : pathlib.Path or str
        The file's name, for messages.
    fh : binary file object
        The data, UTF-8 text (undecodable bytes in comments are kept as they are).
    ext : str
        ``".xyz"``, ``".pts"``, ``".txt"`` or ``".csv"``: ``.pts`` files without a column-name
        line read 4 columns as ``x y z intensity`` and 7 as ``x y z intensity red green blue``.
    columns : sequence of str, optional
        The names of the columns, in their order (every column once, ``x y z`` among them;
        aliases as in a column-name line), instead of the file's column-name line (a note
        says so where they differ) or of the names a file without one gets.

    Returns
    -------
    points : (n, 3) numpy.ndarray
        The ``x y z`` columns (the first three without names), as float64 (empty if the file
        has no data lines).
    normals : (n, 3) numpy.ndarray or None
        The ``nx ny nz`` columns (in a six-column file without names, columns 4-6 where they
        read as normals: see Notes), or None.
    fields : dict of str to (n,) numpy.ndarray
        Every other column, named by the column-name line or ``col3``...: integers (no decimal
        point or exponent anywhere in the column) as int32 (int64 if needed; colours uint8, or
        uint16 beyond 255), others as float64.
    source : object or None
        The leading comment lines, for :func:`payload` to write back; None without data.

    Raises
    ------
    PointCloudFileError
        On fewer than three columns, rows of unequal length, a bad number, a header line (or
        ``columns``) that does not name every column once (x, y and z included), a
        point-count line that does not match the rows (or that claims more than the file can
        hold), or lines of text and no row of numbers (a column-name line alone is a file
        without points).

    Warns
    -----
    PointCloudWarning
        How columns 4-6 of a six-column file without names were read, and where ``columns``
        replaces other names of a column-name line.

    Notes
    -----
    The separator is the first of ``;`` and ``,`` found on the first data line, else tabs and
    spaces; a separator ending a row opens no column. Values may stand in double quotes
    (``"1.5","2"``), and where ``;`` separates them, numbers may be written with a decimal
    comma (``1,5;2,25``). A byte order mark before the first line is dropped (after a UTF-16
    one the file is read as UTF-16, else as UTF-8). ``#`` starts a comment anywhere; a line
    starting with ``//`` before the data is a comment too. A first line holding a single
    integer is a point count (as in PTS files).
    The last line before the data names the columns when it is a bare line
    (``x,y,z,r,g,b``, which must then name every column) or a comment listing as many
    distinct names as there are columns, x, y and z among them. Names are case-insensitive and
    common spellings are mapped: ``r g b`` to ``red green blue``, ``i`` to ``intensity``,
    ``normal_x`` to ``nx``, ``scalar_Intensity`` to ``intensity``...

    Without names (no column-name line, no ``columns``), the first three columns are
    ``x y z``. Columns 4-6 of a six-column file are ``red green blue`` where all three are
    written as integers (no decimal point or exponent in any row) from 0 to 65535; else
    ``nx ny nz`` where every row is a unit vector (length within ``UNIT_TOLERANCE``, 5%, of 1)
    or has no normal (NaN or ``0 0 0``); else fields ``col3`` to ``col5``. Other counts are
    ``x y z`` and fields ``col3``... (``.pts``: see ``ext``).
    """
    raw = fh.read()
    # Windows tools (PowerShell's ">", Notepad's "Unicode") write UTF-16 after a byte order
    # mark. Undecodable bytes are kept as surrogates so that comments are written back verbatim.
    encoding = "utf-16" if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else "utf-8"
    text = raw.decode(encoding, errors="surrogateescape").removeprefix("\ufeff")
    leading, count, pos, lineno = [], None, 0, 1  # leading: (lineno, line, bare)
    while pos < len(text):
        end = text.find("\n", pos)
        end = len(text) if end < 0 else end
        line = text[pos:end].rstrip("\r")
        content = line.split("#", 1)[0]
        if line.strip().startswith(_COMMENT):
            leading.append((lineno, line, False))
        elif content.strip():
            sep = _separator(content)
            tokens = _split(content, sep)
            if not (_is_number(tokens[0]) or _decimal_comma(content, sep)):
                leading.append((lineno, line, True))
            elif count is None and len(tokens) == 1 and tokens[0].isdigit():
                count = int(tokens[0])  # a PTS point-count line, before any data
            else:
                break
        pos, lineno = end + 1, lineno + 1
    if pos >= len(text):
        if count:
            raise PointCloudFileError(f"{path}: first line says {count:,} points but the file "
                                      f"holds none")
        bare = [(at, line) for at, line, is_bare in leading if is_bare]
        if len(bare) > 1:
            # Only the last line before the data may name the columns: these are rows that
            # did not read as numbers.
            at, line = bare[1]
            raise PointCloudFileError(f"{path}: no line holds a row of numbers; line {at} "
                                      f"reads as text: {line.strip()!r}")
        return np.empty((0, 3)), None, {}, None
    ncols = len(tokens)
    if ncols < 3:
        raise PointCloudFileError(f"{path}: line {lineno} has {ncols} columns; x y z need 3")
    # Each row takes at least two characters per value: refuse absurd counts before parsing.
    if count is not None and count * 2 * ncols > len(text) - pos + 1:
        raise PointCloudFileError(f"{path}: first line says {count:,} points, more than the "
                                  f"{len(text) - pos:,} characters after it can hold")
    body = text[pos:]
    comma = _decimal_comma(content, sep)
    if comma:
        body = body.replace(",", ".")
    # Rows ending in their separator hold an empty last field, which the tokens drop.
    trailing = sep is not None and content.rstrip().endswith(sep)
    try:
        data = np.loadtxt(io.StringIO(body), dtype=np.float64, delimiter=sep, comments="#",
                          ndmin=2, usecols=range(ncols) if trailing else None, quotechar='"')
    except ValueError as exc:
        raise _text_parse_error(path, text, pos, lineno, ncols, sep, comma, exc) from None
    if count is not None and count != len(data):
        raise PointCloudFileError(f"{path}: first line says {count:,} points but the file holds "
                                  f"{len(data):,}")
    names = header = None
    if leading:
        at, line, bare = leading[-1]
        # Names given replace a column-name line; a bare line before the data can only be one.
        names = _column_names(path, line, at, sep, ncols, bare and columns is None)
        if names is not None or (bare and columns is not None):
            leading.pop()
            header = (at, names or [line.strip()])
    if columns is not None:
        names = _given_names(path, columns, ncols, header)
    unnamed = names is None
    names = names or _default_names(ncols, ext)
    ints = _integer_columns(data, body, sep, names)
    if unnamed and ncols == 6:
        names = _six_columns(path, data, ints)
    column = {}
    for i, name in enumerate(names):
        column[name] = (ints[i].astype(integer_type(name, ints[i])) if i in ints
                        else np.ascontiguousarray(data[:, i]))
    points = np.column_stack([column.pop(c) for c in COORDS])
    normals = None
    if all(c in column for c in NORMALS):
        normals = np.column_stack([column.pop(c) for c in NORMALS])
    source = _TextSource(tuple(line for _, line, _ in leading))
    return points, normals, column, source


def payload(path, ext, points, normals, fields, source):
    """Prepare a text file: a column-name line, then one row per point.

    Parameters
    ----------
    path : pathlib.Path or str
        The output's name, for messages.
    ext : str
        ``".csv"``: comma-separated with a bare ``x,y,z,...`` name line. ``".pts"``: the point
        count line first (before the source's comments), then ``x y z`` followed by
        ``intensity red green blue`` (those the cloud has), then the other columns; a
        ``# x y z ...`` name line only when the names differ from what a reader infers by
        default. Others: space-separated after ``# x y z ...``.
    points : (n, 3) numpy.ndarray
        Coordinates, the first three columns.
    normals : (n, 3) numpy.ndarray or None
        Normals, the ``nx ny nz`` columns after them.
    fields : dict of str to (n,) numpy.ndarray
        Further columns, each value in the shortest decimal form that reads back equal in
        its own dtype (integers without a decimal point, bool as 0 and 1).
    source : object or None
        What :func:`read` returned for a text input, whose leading comment lines are written
        first, or None.

    Returns
    -------
    callable
        Writes the file to the binary file object it is given, in chunks of rows.
    """
    pts, sep = ext == ".pts", "," if ext == ".csv" else " "
    named = {name: values for name, values in fields.items()}
    columns = {c: points[:, i] for i, c in enumerate(COORDS)}
    if pts:  # the Leica layout first, for readers that take the first seven columns
        columns.update((name, named.pop(name)) for name in _PTS_FIRST if name in named)
    if normals is not None:
        columns.update((c, normals[:, i]) for i, c in enumerate(NORMALS))
    columns.update(named)
    names = list(columns)
    # A PTS file's first line is its point count, which Leica-layout readers take it for.
    head = [str(len(points))] if pts else []
    head += list(source.comments) if source is not None else []
    if ext == ".csv":
        head.append(",".join(names))
    elif not pts or names != _default_names(len(names), ext):
        head.append("# " + " ".join(names))

    def write(fh):
        fh.write("".join(line + "\n" for line in head).encode("utf-8", "surrogateescape"))
        for start in range(0, len(points), TEXT_CHUNK):
            rows = zip(*(decimal_strings(c[start:start + TEXT_CHUNK])
                         for c in columns.values()), strict=True)
            fh.write("".join(sep.join(row) + "\n" for row in rows).encode("ascii"))
    return write
