"""Numba kernels of pssd_fast: plain arrays in, plain arrays out.

Every kernel works on points ``(n, 3) float64`` and a CSR neighbour graph (``indptr`` int64,
``indices`` int32/int64) and writes into caller-allocated output arrays; each output row is
written by exactly one loop iteration, so results do not depend on the number of threads.
This package never imports from the Python layer of ``pssd_fast``.
"""
from . import (bilateral, boxes, cells, feature, graph, knn, likelihood, linalg, mls, noise,
               normals, order, orient, outliers, update)

__all__ = ["bilateral", "boxes", "cells", "feature", "graph", "knn", "likelihood", "linalg",
           "mls", "noise", "normals", "order", "orient", "outliers", "update"]
