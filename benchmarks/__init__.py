"""Benchmarks of pssd_fast: run as scripts (``python -m benchmarks.stages``) or with pytest."""

# First, before pykdtree loads its OpenMP runtime: pssd_fast shortens libgomp's idle spin for
# every pool that loads after it (pssd_fast/__init__.py), as it does in a user's process that
# imports it first.
import pssd_fast  # noqa: F401,E402
