"""The walked fits of the feature-aware step (parameter ``select_scales``; docs/ALGORITHM.md,
"A scale per point"): each point fits nested quadratics over prefixes of its long list and
keeps the widest that still fits. What the walks share is planned before the iterations
(:mod:`pssd_fast.routes.scales`)."""
import numpy as np

from .. import core

#: Prefix lengths are these factors of ``k`` (at least ``smallest``, below the cloud's size);
#: a walk starts at the shortest whose lists span ``radius_over_noise`` noise widths; after
#: the first iteration the walks start at the shortest prefix and test against
#: ``later_noise`` times the first iteration's noise variance. ``tau``, ``tau_cubic`` and
#: ``tau_plane``: the margins of the walk's tests (:func:`pssd_fast.kernels.scales.walk_scales`).
SCALES = {"factors": (0.25, 0.5, 1.0, 2.0, 3.0, 4.5), "smallest": 8,
          "radius_over_noise": 4.0, "later_noise": 0.03, "tau": 3.5, "tau_cubic": 2.5,
          "tau_plane": 1.0}



def fit(points, filtered, graph, lists, sigma_n, walk):
    """The heights of the walked fits, as :func:`pssd_fast.core.aware_fit` gives its own.

    ``graph``: the pipeline's lists of ``k``; ``lists``: the longest prefix's; ``walk``: the
    :class:`~pssd_fast.routes.scales.ScalePlan` of the iteration. Where a walked fit is not
    finite, the default fit at ``k`` (with its robust alternative) stands. Returns the height,
    the RMS residual, the degree (6, or 3 where the plane was taken), the radius of the list
    each height was fitted over and what the walks kept: each point's column (-1 where the fit
    at ``k`` stood) and whether it took the plane.
    """
    k = graph.indices.shape[0] // points.shape[0]
    default, default_rms, degree, coef, across = core.robust_fits(points, filtered, graph,
                                                                   sigma_n)
    fits = core.scale_fits(points, filtered, lists, walk.lengths, sigma_n, k, coef, across)
    height, rms, pick, flat = core.walk_scales(fits, walk.first, walk.noise2, SCALES, default,
                                               default_rms)
    rows = np.arange(points.shape[0])
    walked = np.isfinite(fits.quad[rows, pick])
    degree = np.where(walked, np.where(flat, 3, 6), degree).astype(np.int8)
    support = np.where(walked, fits.radius[rows, pick], graph.list_radius())
    return height, rms, degree, support, np.where(walked, pick, -1), flat & walked


def kept_counts(lengths, pick, flat):
    """An iteration's record of the walks for ``stats``: the ``lengths``, how many points
    kept each (``pick``, -1 for none) and how many took the plane (``flat``)."""
    return {"lengths": lengths.tolist(),
            "kept": np.bincount(pick[pick >= 0], minlength=len(lengths)).tolist(),
            "flat": int(flat.sum())}
