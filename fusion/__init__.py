"""Fusion: from each sensor's bodies to one skeleton per person, with a stable id.

Socket-free and clock-free: the server's sessions feed its engine (:mod:`skelfuse.fusion.engine`)
the decoded frames and the time, and ask it to fuse an instant; offline replay and the benchmarks
drive the same engine in recorded or simulated time. The steps, in order, are in
:mod:`skelfuse.fusion.pipeline`.
"""
