"""A PDAL ``filters.python`` stage that denoises the surfaces of a classified point cloud.

In a pipeline (docs/interop.md has one), give PDAL this file as the stage's ``script``
(``python -m pssd_fast.pdal_filter`` prints its path), ``"function": "denoise"`` and any
``"module"`` name; :func:`stage` makes the stage for PDAL's Python bindings. PDAL's Python
plugins, which run it, are not a dependency of pssd_fast (``pip install pdal-plugins``
compiles them against an installed PDAL: there are no wheels).

PDAL's contract, as its documentation of ``filters.python`` states it (sections "Module
Globals" and "Passing Python objects", and the options ``script``, ``module``, ``function``
and ``pdalargs``) and its Python plugin (``plang/Invocation.cpp``) implements it: PDAL reads
the file named by ``script``, compiles it as a module of the name ``module`` and calls
``function(ins, outs)`` once per point view. ``ins`` maps every dimension of the view to a
1-D numpy array of its points in the dimension's type (``X``, ``Y``, ``Z`` float64,
``Classification`` uint8, ``Intensity`` uint16...); ``outs`` is an empty dict into which the
function puts the arrays it changed, each of its dimension's type and length, and PDAL writes
back only those; the function returns ``True`` (a bool: anything else is an error) and takes
at most two arguments. The stage's ``pdalargs`` option, a JSON object, is in the module's
globals as ``pdalargs`` before each call.

Because PDAL runs this file as a module of its own, outside the package, it imports
pssd_fast by its absolute name.
"""
import json
import time
from pathlib import Path

import numpy as np

import pssd_fast
from pssd_fast.classes import SURFACE_CLASSES, UNCLASSIFIED
from pssd_fast.run import FewPositions
#: The fewest points of a class that are denoised (the library's least cloud); a smaller
#: class in a view keeps its coordinates, with a line in PDAL's log.
MIN_POINTS = 11
#: ``pdalargs`` that the stage cannot take: rows are never dropped (PDAL's ``Mask`` output
#: would have to be the only one), and the classes come from ``Classification``.
REFUSED = ("remove_outliers", "classification", "normals")

#: Set by PDAL before each call to the stage's ``pdalargs`` option (a dict), or left None.
pdalargs = None


def denoise(ins, outs):
    """Denoise the points of a PDAL view, class by class; PDAL's ``filters.python`` function.

    Parameters
    ----------
    ins : dict of str to (n,) ndarray
        Every dimension of the view, as PDAL passes them; ``X``, ``Y`` and ``Z`` are needed,
        ``Classification`` is used where present.
    outs : dict
        Receives ``X``, ``Y`` and ``Z`` (of ``ins``' dtypes) where a class was denoised; no
        other dimension.

    Returns
    -------
    bool
        True, as PDAL requires.

    Notes
    -----
    The module global ``pdalargs`` (PDAL's ``pdalargs`` option) may hold ``classes``: a list
    of class codes, each denoised as a cloud of its own, so that no point of one class is
    another's neighbour (default: the surface classes present in the view,
    :data:`pssd_fast.classes.SURFACE_CLASSES`, as :func:`pssd_fast.denoise` takes them: a view
    of classes 0 and 1 alone is one cloud, one of other classes alone is left as it is), or
    ``"all"``: every point as one cloud, whatever its class. Without a ``Classification`` dimension
    every point is one cloud. Any other key is a keyword of :func:`pssd_fast.denoise`
    (``preset``, ``k``, ``iterations``, ``duplicate_tolerance``, ``n_jobs``...), except
    those in :data:`REFUSED`. Points outside the classes keep their exact coordinates.
    """
    options = _options(pdalargs)
    classes = options.pop("classes", None)
    xyz = np.column_stack([np.asarray(ins[axis], np.float64) for axis in "XYZ"])
    moved = xyz.copy()
    changed = False
    for code, rows in _groups(ins.get("Classification"), classes, xyz.shape[0]):
        name = "every point" if code is None else f"class {code}"
        if rows.shape[0] < MIN_POINTS:
            print(f"pssd_fast: {name}: {rows.shape[0]} points, fewer than {MIN_POINTS}; "
                  f"left as they are")
            continue
        started = time.perf_counter()
        try:
            moved[rows] = pssd_fast.denoise(xyz[rows], **options).points
        except FewPositions as exc:
            if classes is not None or code is None:
                raise
            # A surface class the stage chose, as denoise leaves it.
            print(f"pssd_fast: {name}: {rows.shape[0]} points at {exc.distinct} distinct "
                  f"position{'s' * (exc.distinct != 1)}, fewer than {MIN_POINTS}; left as "
                  f"they are")
            continue
        changed = True
        print(f"pssd_fast: {name}: {rows.shape[0]} points denoised in "
              f"{time.perf_counter() - started:.1f} s")
    if changed:
        for axis, column in zip("XYZ", moved.T):
            outs[axis] = np.ascontiguousarray(column, dtype=ins[axis].dtype)
    return True


def stage(**options):
    """The ``filters.python`` stage of a PDAL pipeline that runs :func:`denoise`.

    Parameters
    ----------
    **options
        Its ``pdalargs``: ``classes`` and :func:`pssd_fast.denoise`'s keywords (see
        :func:`denoise`).

    Returns
    -------
    dict
        ``type``, ``script`` (the path of this file), ``module``, ``function`` and ``pdalargs``
        (JSON text, as PDAL's documentation writes it), for ``pdal.Pipeline`` or a pipeline
        file.

    Examples
    --------
    >>> from pssd_fast import pdal_filter
    >>> step = pdal_filter.stage(classes=[2, 6], preset="fast")
    >>> step["type"], step["function"], step["pdalargs"]
    ('filters.python', 'denoise', '{"classes": [2, 6], "preset": "fast"}')
    """
    _options(options)
    return {"type": "filters.python", "script": str(Path(__file__).resolve()),
            "module": "pssd_fast_pdal", "function": "denoise", "pdalargs": json.dumps(options)}


def _options(given):
    """``pdalargs`` as a new dict of keywords: None is no option, JSON text is read."""
    if given is None:
        return {}
    if isinstance(given, str):
        given = json.loads(given) if given.strip() else {}
    if not isinstance(given, dict):
        raise TypeError(f"pdalargs must be a JSON object; got {given!r}")
    refused = sorted(set(given) & set(REFUSED))
    if refused:
        raise ValueError(f"pdalargs {', '.join(refused)}: not in a PDAL stage (rows are never "
                         f"dropped, the classes come from Classification and its 'classes')")
    return dict(given)


def _groups(labels, classes, n):
    """``(class code or None, rows)`` of each cloud to denoise."""
    if isinstance(classes, str):
        if classes != "all":
            raise ValueError(f"pdalargs classes must be a list of class codes or 'all'; got "
                             f"{classes!r}")
        return [(None, np.arange(n))]
    if labels is None:
        if classes is not None:
            raise ValueError("pdalargs classes needs a Classification dimension; the view has "
                             "none (pass 'all' to denoise every point)")
        return [(None, np.arange(n))]
    labels = np.asarray(labels)
    if classes is None and np.isin(labels, UNCLASSIFIED).all():
        return [(None, np.arange(n))]  # classes 0 and 1 alone: no classification, as denoise
    if classes is None:
        wanted = [code for code in SURFACE_CLASSES if (labels == code).any()]
    else:
        codes = [classes] if isinstance(classes, int) else classes
        if not isinstance(codes, list) or not all(
                isinstance(c, int) and not isinstance(c, bool) for c in codes):
            raise TypeError(f"pdalargs classes must be a list of class codes; got {classes!r}")
        wanted = sorted(set(codes))
    return [(code, np.flatnonzero(labels == code)) for code in wanted]


if __name__ == "__main__":
    # The path to give PDAL as the stage's script.
    print(Path(__file__).resolve())
