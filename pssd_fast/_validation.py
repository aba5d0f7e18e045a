"""Argument checks, run before any kernel: each error names the bad value and how to fix it."""
import numbers
import os
import sys
import warnings

import numpy as np

from . import interop

# The cubic of eq. (1) has 10 coefficients: fewer neighbours cannot determine it.
MIN_K = 10
#: float32 coordinates warn where their step at the largest coordinate exceeds this fraction of
#: the cloud's mean spacing (docs/DECISIONS.md, "float32 coordinates far from the origin").
STEP_OF_SPACING = 0.01
#: Rows of the sample that estimates the mean spacing, and of its queries.
SPACING_SAMPLE = (20_000, 1_000)
#: The smallest extent and the largest absolute coordinate of a cloud the kernels compute in:
#: squared distances overflow float64 beyond about 1e154 and vanish below about 1e-154, and
#: the fits' moments go to higher powers of the offsets than the squares.
COORDINATE_RANGE = (1e-100, 1e100)


#: A distance more than this many times the median of its kind belongs to a point off the
#: surface (a stray return, a "no return" row at the origin): :func:`surface_mean`.
STRAY = 100.0


class DenoiseWarning(UserWarning):
    """Something of a run the caller may not expect: coordinates whose float32 steps are coarse
    against the cloud's spacing, or classes too small to denoise, left as they are."""


#: This package's folder: a warning names the first caller outside it (:func:`warn`).
_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn(message):
    """A :class:`DenoiseWarning` of ``message`` at the first caller outside this package, however
    deep in it the warning arises (a class's run, a tiled run, the plan): so that a caller's
    filters by module and its once-per-place warnings apply."""
    frame, level = sys._getframe(1), 2
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, DenoiseWarning, stacklevel=level)


def as_points(points, name="points"):
    """Return ``points`` as a C-contiguous, writable ``(n, 3) float64`` copy-or-view, checking
    it first. A read-only array is copied: the kernels then run with the signatures they
    compile for every run, not with one more of their own (each a compile of its own on a
    first run, a load on every later one).

    Returns
    -------
    array : (n, 3) float64
    dtype : numpy.dtype
        The dtype results should be returned in (float32 stays float32, everything else float64).
    """
    if isinstance(points, (str, os.PathLike)):
        raise TypeError(f"{name} must be an (n, 3) array, not the file name {str(points)!r}; "
                        f"read the file first: pssd_fast.io.read({str(points)!r}).points")
    if isinstance(points, np.ndarray):
        arr = points
    else:
        try:
            arr = np.asarray(points)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{name} must be an array-like of shape (n, 3); got "
                            f"{type(points).__name__} ({exc})") from None
    if isinstance(arr, np.ma.MaskedArray) and np.ma.getmaskarray(arr).any():
        raise TypeError(f"{name} is a masked array with {int(np.ma.getmaskarray(arr).sum())} "
                        f"masked value(s), which denoising cannot leave out; pass the rows to "
                        f"denoise, such as {name}.data[~{name}.mask.any(axis=1)]")
    if arr.dtype.kind == "O" and arr.ndim == 0:
        # An object numpy cannot read as numbers: say how to get its coordinates.
        raise TypeError(f"{name} must be an (n, 3) array of real numbers; got "
                        f"{interop.type_name(points)}"
                        f"{interop.hint(points) if name == 'points' else ''}")
    if arr.dtype.kind not in "fiu":
        kind = {"c": "complex", "O": "object", "b": "boolean"}.get(arr.dtype.kind, str(arr.dtype))
        raise TypeError(f"{name} must hold real numbers; got dtype {arr.dtype} ({kind}); "
                        f"convert it with .astype(np.float64)")
    if arr.ndim != 2 or arr.shape[1] != 3:
        hint = ""
        if arr.ndim == 2 and arr.shape[0] == 3:
            hint = (f"; if this is a (3, n) array of "
                    f"{'coordinates' if name == 'points' else name}, pass its transpose .T")
        raise ValueError(f"{name} must have shape (n, 3); got shape {arr.shape}{hint}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name} is empty (shape {arr.shape}); pass at least k + 1 points")
    out_dtype = np.dtype(np.float32) if arr.dtype == np.float32 else np.dtype(np.float64)
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} contains NaN or Inf in {int(bad.sum())} row(s); the first is "
                         f"row {first}: {arr[first].tolist()}; drop or repair those rows")
    if name == "points":
        check_range(arr.min(axis=0), arr.max(axis=0))
    if not arr.flags.writeable:
        arr = arr.copy()
    return arr, out_dtype


def check_range(low, high):
    """ValueError where a cloud's extent or coordinates (its bounding box's corners ``low``
    and ``high``) lie outside :data:`COORDINATE_RANGE` (a cloud at one position is named
    later, as too few points)."""
    smallest, largest = COORDINATE_RANGE
    reach = float(max(np.abs(low).max(), np.abs(high).max()))
    extent = float((high - low).max())
    if reach > largest or 0.0 < extent < smallest:
        raise ValueError(
            f"points reach {reach:.3g} and span {extent:.3g}: denoising computes with "
            f"squared distances, which float64 holds for coordinates up to {largest:.0e} and "
            f"extents from {smallest:.0e}; rescale the cloud (for example, subtract its "
            f"centre and divide by its extent) and scale the result back")


def check_precision(points, dtype, largest=None):
    """Warn (:class:`DenoiseWarning`) where ``points`` (float64, as :func:`as_points` returns
    them) came as float32 whose step at their largest absolute coordinate (``largest``, or
    theirs) exceeds :data:`STEP_OF_SPACING` of the cloud's mean spacing
    (:func:`mean_spacing`, which reads them ``[::step]`` only)."""
    if dtype != np.float32:
        return
    largest = float(np.abs(points).max()) if largest is None else largest
    step = float(np.spacing(np.float32(largest)))
    spacing = mean_spacing(points)
    if not step > STEP_OF_SPACING * spacing:
        return
    against = (f"{step / spacing:.0%} of the cloud's mean spacing ({spacing:.3g})" if spacing
               else "more than the spacing of its points, which share positions")
    warn(
        f"points are float32 and reach {largest:.7g}, where float32 values are {step:.3g} "
        f"apart: {against}, so the coordinates lost detail that denoising works at, and the "
        f"float32 result is rounded to that step; pass float64 coordinates, or subtract an "
        f"offset (such as the bounding box's low corner) before converting them to float32")


def on_surface(values, stray=STRAY):
    """The mask of the points on the surface: those whose distances ``values`` are within
    ``stray`` times their median."""
    return values <= stray * np.median(values)


def surface_mean(values, stray=STRAY, of=None):
    """The mean of ``of`` (by default the distances ``values`` themselves) over the points on
    the surface (:func:`on_surface`). One point far from the rest would otherwise set it
    alone."""
    of = values if of is None else of
    on = on_surface(values, stray)
    return float(np.mean(of if on.all() else of[on]))


def mean_spacing(points):
    """The mean distance to the nearest other position, estimated cheaply: of up to 1,000 rows
    among up to 20,000 rows taken at a fixed stride (:data:`SPACING_SAMPLE`), times the square
    root of the fraction of rows taken (a surface's spacing goes as one over the square root
    of its density); 0 where every sampled row has a copy only. Stray points are left out as
    the noise probe leaves them out (:func:`surface_mean`): one of them would set the mean
    alone."""
    from ._threads import kdtree  # _threads imports this module

    n = points.shape[0]
    sample = points[::max(1, n // SPACING_SAMPLE[0])]
    queries = sample[::max(1, sample.shape[0] // SPACING_SAMPLE[1])]
    if sample.shape[0] < 2:
        return 0.0
    distance, _ = kdtree(sample).query(queries, k=2)
    # Copies are one position: the nearest other position is farther than 0.
    found = distance[:, 1][distance[:, 1] > 0]
    return surface_mean(found) * float(np.sqrt(sample.shape[0] / n)) if found.size else 0.0


def as_normals(normals, n, name="normals"):
    """Return ``normals`` as a unit-length ``(n, 3) float64`` array matching ``n`` points."""
    arr, _ = as_points(normals, name)
    if arr.shape[0] != n:
        raise ValueError(f"{name} must have one row per point: got {arr.shape[0]} rows for "
                         f"{n} points")
    length = np.linalg.norm(arr, axis=1)
    zero = ~(length > 0.0)
    if zero.any():
        first = int(np.flatnonzero(zero)[0])
        raise ValueError(f"{name} has {int(zero.sum())} zero-length row(s), the first is row "
                         f"{first}; pass normals=None to estimate them")
    return arr / length[:, None]


#: Named orientations of :func:`pssd_fast.estimate_normals` and :func:`pssd_fast.denoise`.
ORIENTATIONS = ("outward", "up")


def check_orient(orient):
    """``"outward"``, ``"up"`` or a viewpoint as a finite ``(3,) float64`` array."""
    if isinstance(orient, str):
        return check_choice(orient, "orient", ORIENTATIONS)
    try:
        view = np.asarray(orient, dtype=np.float64)
    except (TypeError, ValueError):
        view = None
    if view is None or view.shape != (3,) or not np.isfinite(view).all():
        raise ValueError(f"orient must be 'outward', 'up' or a viewpoint (3 finite numbers); "
                         f"got {orient!r}")
    return view


def check_orient_estimated(orient, has_normals, source="the given normals",
                           fix="drop orient, or pass normals=None"):
    """Raise where ``orient`` is set although the normals are given (by ``source``): only
    estimated normals are turned; given normals keep their signs."""
    if orient is not None and has_normals:
        raise ValueError(f"orient applies to estimated normals; {source} keep their signs "
                         f"({fix})")


def check_k(k, n_points, minimum=MIN_K, denoising=True):
    """Check the neighbour count against the cubic's needs and the cloud's size (``denoising``:
    a cloud too small for any ``k`` is refused as too small to denoise; else as too small for
    lists of ``k``)."""
    k = check_int(k, "k", minimum=minimum)
    if n_points < k + 1:
        if denoising:
            check_size(n_points, minimum)
        lower = "lower k or pass" if n_points >= minimum + 1 else f"k is at least {minimum}: pass"
        raise ValueError(f"need at least k + 1 = {k + 1} points for k = {k}; got {n_points} "
                         f"point{'s' * (n_points != 1)} ({lower} a larger cloud)")
    return k


def check_size(n_points, minimum=MIN_K):
    """Refuse a cloud too small for any allowed ``k`` (``minimum`` neighbours and the point)."""
    if n_points < minimum + 1:
        raise ValueError(f"the cloud has {n_points} point{'s' * (n_points != 1)}; denoising "
                         f"needs at least {minimum + 1}")


def check_int(value, name, minimum=None, maximum=None):
    """Return ``value`` as an int, rejecting bools, floats and values outside ``[minimum,
    maximum]``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer; got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be at least {minimum}; got {value}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be at most {maximum}; got {value}")
    return value


def check_float(value, name, low=None, high=None, positive=False):
    """Return ``value`` as a finite float within ``[low, high]`` (``> 0`` if ``positive``)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number; got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise ValueError(f"{name} must be finite; got {value}")
    if positive and not value > 0.0:
        raise ValueError(f"{name} must be positive; got {value}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise ValueError(f"{name} must lie in [{low}, {high}]; got {value}")
    return value


def check_choice(value, name, choices):
    """Check that ``value`` is one of ``choices`` (strings)."""
    if value not in choices:
        raise ValueError(f"unknown {name} {value!r}; choose one of "
                         + ", ".join(repr(c) for c in choices))
    return value


def auto(value, check=None):
    """None where ``value`` leaves the choice to the library (``"auto"``, or None as calls
    written before ``"auto"`` pass it), else ``check(value)`` (or ``value``)."""
    if value is None or (isinstance(value, str) and value == "auto"):
        return None
    return value if check is None else check(value)


def check_flag(value, name):
    """``value`` as a bool, or None for ``"auto"``; TypeError otherwise."""
    value = auto(value)
    if value is not None and not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True, False or 'auto'; got {value!r}")
    return None if value is None else bool(value)


def seeded_rng(seed):
    """``np.random.default_rng(seed)`` for a non-negative integer seed only (reproducibility)."""
    return np.random.default_rng(check_int(seed, "seed", minimum=0))
