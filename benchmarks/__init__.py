"""Benchmarks: figures, not tests. Each runs from the repository root as `python -m benchmarks.NAME --help`."""
