"""Benchmarks of pssd_fast: run as scripts (``python -m benchmarks.stages``) or with pytest."""

# First, before any benchmark imports pykdtree: its OpenMP pool and numba's load with the
# library's short idle spin, as they do in a user's process that calls pssd_fast first.
import pssd_fast

pssd_fast.configure_threads()
