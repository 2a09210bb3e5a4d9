"""Benchmarks by subject; run one with ``python -m bench NAME`` (the list: ``python -m bench``).

Results and their commands are in docs/benchmarks.md.
"""
