"""LiDAR classes kept apart: which classes a :func:`pssd_fast.denoise` call with
``classification=`` denoises, and the one result of their runs, each class on its own."""
import dataclasses
import numbers
import time
from contextlib import contextmanager

import numpy as np

from ._validation import MIN_K, as_normals, check_int, warn
from .plan import PRESETS
from .run import Deferred, DenoiseResult, FewPositions, stored

#: The ASPRS LAS 1.4 classes that are surfaces, denoised by default: each on its own.
SURFACE_CLASSES = {2: "ground", 6: "building", 9: "water", 10: "rail", 11: "road surface",
                   17: "bridge deck"}
#: Classes that say a point was never classified (0) or not assigned a class (1): a
#: classification of these alone is no classification.
UNCLASSIFIED = (0, 1)
#: What ``classes=`` takes besides class codes.
NAMED = ("all", "each")
#: The entries of a run's ``stats`` that a classes call sums over its runs.
SUMMED = ("n_points", "duplicates", "held_points")


def select(classification, classes, n, options):
    """The runs of a call of :func:`pssd_fast.denoise` with ``classification`` and
    ``classes`` on ``n`` points: ``(code, rows)`` for each class to denoise on its own (rows
    increasing; code None and every row for one cloud); ``(code, points, None)`` of the classes
    too small to denoise; what ``stats["classes"]["classes"]`` says; and the fewest points a run
    takes. ValueError or TypeError naming what is wrong. ``options``: the call's other
    options (``k`` and ``preset`` decide what is too small)."""
    least = least_points(options)
    whole = [(None, np.arange(n))], [], "all", least
    check_classes(classification, classes)
    labels = None if classification is None else check_labels(classification, n)
    if labels is None or _name(classes) == "all":
        return whole
    codes, rows = _by_class(labels)
    chosen, small = choose(codes, [r.shape[0] for r in rows], classes, least)
    if chosen is None:
        return whole
    rows = dict(zip(codes.tolist(), rows))
    return [(code, rows[code]) for code in chosen], small, chosen, least


def check_classes(classification, classes):
    """ValueError where ``classes`` is no choice, or is given without a ``classification``."""
    if isinstance(classes, str) and classes not in NAMED:
        raise ValueError(f"classes must be class codes, 'each' or 'all'; got {classes!r}")
    if classification is None and classes is not None and _name(classes) != "all":
        raise ValueError("classes and classification go together: classification=... gives "
                         "each point's class, classes=... those to denoise")


def choose(codes, sizes, classes, least):
    """The classes of a classification to denoise, each on its own: their codes (increasing;
    None where the cloud runs as one) and ``(code, points, None)`` of those too small to run
    (fewer than ``least`` points; 0 for a class asked for that no point is of); ``codes``:
    the classes present, increasing, with their ``sizes``. ValueError or TypeError naming
    what is wrong."""
    codes = np.asarray(codes)
    present = ", ".join(str(c) for c in codes[:20]) + (", ..." if len(codes) > 20 else "")
    small = []
    if classes is None:
        if np.isin(codes, UNCLASSIFIED).all():
            return None, []
        wanted = np.isin(codes, list(SURFACE_CLASSES))
        if not wanted.any():
            raise ValueError(
                f"no point is of a surface class ({_named(SURFACE_CLASSES)}), which a "
                f"classification denoises by default; the classes present are {present}: name "
                f"the classes to denoise (classes= or --classes: codes, each, or all for every "
                f"point as one cloud)")
    elif _name(classes) == "each":
        wanted = np.ones(len(codes), np.bool_)
    else:
        asked = _codes(classes)
        wanted = np.isin(codes, asked)
        if not wanted.any():
            raise ValueError(f"no point is of class {', '.join(map(str, asked))}; the classes "
                             f"present are {present}")
        # Classes asked for that no point is of: a pipeline over many files names them all.
        small = [(int(c), 0, None) for c in np.setdiff1d(asked, codes)]
    chosen = [(int(c), int(size)) for c, size, w in zip(codes, sizes, wanted) if w]
    if classes is None or _name(classes) == "each":
        # Classes the library chose: those too small for a run are left as they are.
        small = [(c, size, None) for c, size in chosen if size < least]
        chosen = [(c, size) for c, size in chosen if size >= least]
        if not chosen:
            raise ValueError(f"no class to denoise has the {least} points a run needs; the "
                             f"classes present are {present}")
    return [c for c, _ in chosen], small


def warn_small(small, least):
    """One :class:`DenoiseWarning` naming the classes too small to denoise, if any
    (``(code, points, distinct positions or None)``; those of no point among them: asked
    for, absent)."""
    absent = [str(code) for code, size, _ in sorted(small) if size == 0]
    few = [f"{code} ({size:,} points" + ("" if distinct is None else
                                         f" at {distinct:,} distinct position"
                                         f"{'s' * (distinct != 1)}") + ")"
           for code, size, distinct in sorted(small) if size > 0]
    said = ([f"no point is of class {' or '.join(absent)}"] if absent else []) + (
        [f"class{'es' * (len(few) > 1)} {', '.join(few)}: fewer points than a run needs "
         f"({least}); left as they are"] if few else [])
    if said:
        warn("; ".join(said))


def denoise_each(pts, dtype, normals, classification, classes, options, denoise, started):
    """Each class that ``classification`` and ``classes`` choose denoised on its own by
    ``denoise(points, normals)``, the other points kept as they are (:func:`merge`); a class
    the library chose and too small for a run is left as it is, with a warning.
    ``pts``: float64 coordinates, returned as ``dtype``; ``options``: the call's other
    options (:func:`select`)."""
    n = pts.shape[0]
    runs, small, described, least = select(classification, classes, n, options)
    chosen = np.zeros(n, np.bool_)
    for _, rows in runs:
        chosen[rows] = True
    given = given_normals(normals, n, chosen)
    done = []
    for code, rows in runs:
        with naming(code), too_few(code, rows.shape[0], classes, small):
            done.append((code, rows, denoise(pts[rows], None if given is None else given[rows])))
    warn_small(small, least)
    check_some(done, least)
    return merge(pts, dtype, given, done, small, described, started)


@contextmanager
def too_few(code, size, classes, small):
    """A class the library chose (``classes`` None or "each") whose ``size`` points have too
    few distinct positions for a run (:class:`pssd_fast.run.FewPositions`) is added to
    ``small`` and left as it is, as one of too few points is (:func:`choose`)."""
    try:
        yield
    except FewPositions as exc:
        if code is None or not (classes is None or _name(classes) == "each"):
            raise
        small.append((code, size, exc.distinct))


def check_some(done, least):
    """ValueError where no class was denoised: each the library chose had too few distinct
    positions (:func:`too_few`)."""
    if not done:
        raise ValueError(f"no class to denoise has the {least} distinct positions a run needs")


@contextmanager
def naming(code):
    """A ValueError of the run of class ``code`` says which class it was (None: no class)."""
    try:
        yield
    except ValueError as exc:
        if code is None:
            raise
        raise ValueError(f"the points of class {code}: {exc}") from exc


def merge(pts, dtype, given, done, small, described, started):
    """One :class:`DenoiseResult` from the runs ``done`` (``(code, rows, result)``) on the
    float64 ``pts`` (``given``: the caller's float64 normals, or None): the rows of no run keep
    their coordinates and normals (else NaN), NaN fields and zero displacement."""
    n = pts.shape[0]
    holds = np.ones(n, np.bool_)
    chosen = np.zeros(n, np.bool_)
    for _, rows, part in done:
        chosen[rows] = True
        holds[rows] = False
        holds[rows[part.kept]] = True
    kept = np.flatnonzero(holds)
    # Each row's place among the kept rows.
    place = np.cumsum(holds) - 1
    out_points = pts[kept].astype(dtype)
    out_normals = (np.full((kept.shape[0], 3), np.nan, dtype) if given is None
                   else given[kept].astype(dtype))
    first = done[0][2]
    places = [place[rows[part.kept]] for _, rows, part in done]

    def merged(name, fill):
        values = np.full(kept.shape[0], fill, dtype if name != "held" else np.bool_)
        for at, (_, _, part) in zip(places, done, strict=True):
            values[at] = getattr(part, name)
        return values

    arrays = {}
    for name, fill in (("likelihood", np.nan), ("feature_intensity", np.nan),
                       ("displacement", 0), ("held", False), ("outlier_score", np.nan)):
        if stored(first, name) is None:
            arrays[name] = None
        elif any(type(stored(part, name)) is Deferred for _, _, part in done):
            # Read from each run's result when the merged one's is first read.
            arrays[name] = Deferred(lambda name=name, fill=fill: merged(name, fill))
        else:
            arrays[name] = merged(name, fill)
    for at, (_, _, part) in zip(places, done, strict=True):
        out_points[at] = part.points
        out_normals[at] = part.normals
    stats = summary([(code, rows.shape[0], part.stats) for code, rows, part in done],
                    int(n - chosen.sum()), small, described, started)
    return DenoiseResult(points=out_points, normals=out_normals, kept=kept, stats=stats,
                         **arrays)


def summary(runs, untouched, small, described, started):
    """The ``stats`` of a classes call from those of its ``runs`` (``(code, points,
    stats)``), the number of points of no run (``untouched``) and the classes too ``small``:
    the largest run's, with :data:`SUMMED`, the outliers and the tiles (their count and the
    seconds of a file's passes summed; their most points the largest) over the runs and
    ``stats["classes"]`` added."""
    largest = max(runs, key=lambda run: run[1])[2]
    tiles = largest.tiles
    if tiles is not None:
        # Every class's tiles, not the largest's alone.
        tiles = {**tiles, "count": sum(run[2].tiles["count"] for run in runs),
                 "most_points": max(run[2].tiles["most_points"] for run in runs)}
        for when in ("before", "after"):  # a file's passes, each class's
            if when in tiles:
                tiles[when] = {stage: sum(run[2].tiles[when].get(stage, 0.0) for run in runs)
                               for stage in tiles[when]}
    return dataclasses.replace(
        largest, **{name: sum(run[2][name] for run in runs) for name in SUMMED}, tiles=tiles,
        outliers=_outliers([run[2]["outliers"] for run in runs]),
        total_seconds=time.perf_counter() - started,
        classes={"classes": described, "denoised": int(sum(run[1] for run in runs)),
                 "untouched": untouched,
                 "too_small": sorted(code for code, size, _ in small if size),
                 "runs": {} if described == "all" else {code: found for code, _, found in runs}})


def given_normals(normals, n, chosen):
    """The caller's ``normals`` as float64, those of the ``chosen`` rows checked; the others
    are kept as given, NaN included (as a classes run returns them where none were given)."""
    if normals is None:
        return None
    given = np.asarray(normals)
    if given.shape != (n, 3):
        as_normals(normals, n)  # names what is wrong
    name = "normals" if chosen.all() else "normals (of the chosen classes)"
    used = as_normals(given[chosen], int(chosen.sum()), name)
    given = given.astype(np.float64)
    given[chosen] = used
    return given


def _name(classes):
    """``classes`` where it is a name, else None (codes)."""
    return classes if isinstance(classes, str) else None


def check_labels(classification, n):
    """``classification`` as an array of ``n`` integers, checked."""
    labels = np.asarray(classification)
    if labels.shape != (n,):
        raise ValueError(f"classification must have one value per point, shape ({n},); got "
                         f"shape {labels.shape}")
    if labels.dtype.kind not in "iu":
        raise TypeError(f"classification must hold integers; got dtype {labels.dtype}")
    return labels


def _by_class(labels):
    """The classes present, increasing, and the rows of each, increasing: one sort in all."""
    order = np.argsort(labels, kind="stable")
    codes, starts = np.unique(labels[order], return_index=True)
    return codes, np.split(order, starts[1:])


def _codes(classes):
    """The class codes ``classes`` names, sorted, checked."""
    if isinstance(classes, numbers.Integral):
        classes = [classes]
    try:
        wanted = sorted({check_int(c, "a class") for c in classes})
    except TypeError as exc:
        raise TypeError(f"classes must be integers, 'each' or 'all'; got {classes!r}") from exc
    if not wanted:
        raise ValueError("classes is empty: name at least one class to denoise")
    return wanted


def least_points(options):
    """The fewest points a run with ``options`` takes: ``k + 1``, the preset's."""
    k = options.get("k")
    if isinstance(k, numbers.Integral) and not isinstance(k, bool):
        return int(k) + 1
    preset = PRESETS.get(options.get("preset"), {})
    return (preset.get("k") or MIN_K) + 1


def _named(classes):
    """``2 ground, 6 building...``"""
    return ", ".join(f"{code} {name}" for code, name in classes.items())


def _outliers(records):
    """What ``remove_outliers`` did over the runs, or None where it did not run."""
    if records[0] is None:
        return None
    return {name: sum(record[name] for record in records) for name in records[0]}
