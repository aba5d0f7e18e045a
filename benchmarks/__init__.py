"""Benchmarks of pssd_fast: run as scripts (``python -m benchmarks.stages``) or with pytest."""
