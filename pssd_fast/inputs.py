"""The normals each iteration of :func:`pssd_fast.denoise` estimates, and their signs."""
from . import core

#: The shifted normals of the feature-aware pipeline's first iteration (docs/ALGORITHM.md,
#: "Shifted normals"): the candidates are the first ``candidates`` times ``k`` entries of each
#: list, and a candidate's plane qualifies within ``tolerance`` times its RMS spread.
SHIFT = {"candidates": 0.25, "tolerance": 2.0}


def estimated_normals(points, graph, previous, orient, centre, shift_k=None):
    """PCA normals signed like the ``previous`` iteration's, else by ``orient`` (propagation)
    or away from the centroid (``orient=None``); ``points`` are relative to ``centre``.
    ``shift_k``: the lists' ``k``, to replace the normals by
    :func:`pssd_fast.core.shifted_normals` (same signs), or None."""
    hints = core.outward_hints(points) if previous is None else previous
    nrm, degenerate = core.pca_normals(points, graph, hints)
    if orient is not None:
        core.orient_normals(points, nrm, graph, orient if isinstance(orient, str)
                            else orient - centre)
    if shift_k is not None:
        nrm = shifted(points, nrm, graph, shift_k)
    return nrm, degenerate


def shifted(points, nrm, graph, k):
    """:func:`pssd_fast.core.shifted_normals` at the constants of :data:`SHIFT`, for lists of
    ``k`` neighbours."""
    return core.shifted_normals(points, nrm, graph, max(1, round(SHIFT["candidates"] * k)),
                                SHIFT["tolerance"])
