"""The normals each iteration of :func:`pssd_fast.denoise` estimates, and their signs."""
from . import core


def estimated_normals(points, graph, previous, orient, centre):
    """PCA normals signed like the ``previous`` iteration's, else by ``orient`` (propagation)
    or away from the centroid (``orient=None``); ``points`` are relative to ``centre``."""
    hints = core.outward_hints(points) if previous is None else previous
    nrm, degenerate = core.pca_normals(points, graph, hints)
    if orient is not None:
        core.orient_normals(points, nrm, graph, orient if isinstance(orient, str)
                            else orient - centre)
    return nrm, degenerate
