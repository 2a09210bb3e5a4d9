"""Fusion: from each sensor's bodies to one skeleton per person, with a stable id.

Socket-free and clock-free: the server's sessions feed its engine (:mod:`skelfuse.fusion.engine`)
the decoded frames and the time, and ask it to fuse an instant; offline replay and the benchmarks
drive the same engine in recorded or simulated time. The steps, in order, are in
:mod:`skelfuse.fusion.pipeline`.

Fusion needs numba (its hot stages are compiled loops, one implementation each) and numpy 2: the
``fusion`` extra, which the ``server`` extra includes. Importing it without them fails here, with
the install line, rather than halfway through a take.
"""

from skelfuse.jit import require_fusion_dependencies

require_fusion_dependencies()
