"""The normals each iteration of :func:`pssd_fast.denoise` estimates, and their signs."""
from .. import core

#: The shifted normals of the feature-aware pipeline's first iteration (docs/ALGORITHM.md,
#: "Shifted normals"): the candidates are the first ``candidates`` times ``k`` entries of each
#: list, and a candidate's plane qualifies within ``tolerance`` times its RMS spread.
SHIFT = {"candidates": 0.25, "tolerance": 2.0}


def estimated_normals(points, graph, previous, orient, centre, shift_k=None):
    """PCA normals signed like the ``previous`` iteration's, else by ``orient`` (propagation)
    or away from the centroid (``orient=None``); ``points`` are relative to ``centre``.
    ``shift_k``: the lists' ``k``, to replace the normals by :func:`shifted` ones (same signs),
    or None."""
    hints = core.outward_hints(points) if previous is None else previous
    nrm, degenerate, planes = pca(points, graph, hints, shift_k is not None)
    if orient is not None:
        core.orient_normals(points, nrm, graph, orient if isinstance(orient, str)
                            else orient - centre)
    if shift_k is not None:
        nrm = shifted(points, nrm, graph, planes, shift_k)
    return nrm, degenerate


def pca(points, graph, hints, planes):
    """PCA normals signed along ``hints`` and the mask of degenerate lists; with ``planes``,
    from :func:`pssd_fast.core.list_planes`, which also gives the planes :func:`shifted`
    reads (else None), so the lists are decomposed once."""
    if not planes:
        return (*core.pca_normals(points, graph, hints), None)
    found = core.list_planes(points, graph, hints)
    return found.normals.copy(), found.degenerate, found


def shifted(points, nrm, graph, planes, k):
    """:func:`pssd_fast.core.shifted_normals` at the constants of :data:`SHIFT`, for lists of
    ``k`` neighbours and their ``planes``."""
    return core.shifted_normals(points, nrm, graph, planes,
                                max(1, round(SHIFT["candidates"] * k)), SHIFT["tolerance"])
