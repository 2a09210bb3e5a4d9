"""skelfuse: markerless multi-sensor motion capture.

One import root; the layers, bottom up (import-linter checks that they only point down):
``geometry`` (shared math: rotations, pinhole cameras) beside the process settings
``skelfuse.jit``, ``skelfuse.blas`` and ``skelfuse.parent_watch`` ← ``protocol`` (wire, file
formats, feed messages) ← ``calibration``, ``agent`` and ``client`` ← ``fusion`` ← ``recording``
← ``server`` ← the command line (``skelfuse.cli``, ``skelfuse.demo``).
"""

__version__ = "0.1.0"
