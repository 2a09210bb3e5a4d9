"""Fusion accuracy against simulated ground truth: the methods, alignment policies, lag."""
