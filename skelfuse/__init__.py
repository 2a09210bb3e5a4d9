"""skelfuse: markerless multi-sensor motion capture.

One import root; the layers, bottom up (import-linter checks that they only point down):
``protocol`` (wire, file formats, feed messages) ← ``calibration`` and ``agent`` ← ``fusion``
← ``recording`` ← ``server`` ← the command line (``skelfuse.cli``, ``skelfuse.demo``).
"""

__version__ = "0.1.0"
