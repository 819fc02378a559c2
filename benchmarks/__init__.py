"""pointclm's benchmarks, one package per suite (see benchmarks/README.md).

Run them as modules from the repository root, e.g. ``python -m benchmarks.bins.run --help``.
"""
