"""Fusion: from each sensor's bodies to one skeleton per person, with a stable id.

Socket-free and clock-free: the server feeds it what arrives and asks it to fuse an instant; offline
replay and the benchmarks drive the same code in recorded or simulated time. The steps, in order,
are in :mod:`skelfuse.fusion.pipeline`.
"""
