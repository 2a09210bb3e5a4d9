"""Simulated sensors and performers for demos, tests and benchmarks."""
