"""Which points lie in a tile's halo: inside any of a few boxes (:mod:`pssd_fast.regions`)."""
import numpy as np
from numba import prange

from .config import CHUNK, parallel_kernel


@parallel_kernel
def inside_any(points, boxes, out):
    """Whether each point lies inside any of ``boxes``, faces included.

    Parameters
    ----------
    points : (n, 3) float64
    boxes : (p, 2, 3) float64
        Each box's low and high corner.
    out : (n,) bool
        Output: ``low <= p <= high`` on every axis for some box.
    """
    n = points.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            x, y, z = points[i, 0], points[i, 1], points[i, 2]
            hit = False
            for b in range(boxes.shape[0]):
                if (boxes[b, 0, 0] <= x <= boxes[b, 1, 0] and boxes[b, 0, 1] <= y <= boxes[b, 1, 1]
                        and boxes[b, 0, 2] <= z <= boxes[b, 1, 2]):
                    hit = True
                    break
            out[i] = np.bool_(hit)
