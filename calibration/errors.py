"""Errors raised by the calibration math.

::

    CalibrationError                 base of every calibration error (catch this at the API edge)
    ├── InvalidInput                 wrong shape, NaN/inf where numbers are required, empty input
    ├── NotEnoughCorrespondences     fewer pairs/frames than the method needs
    ├── DegenerateGeometry           the pairs do not pin down a pose (collinear, coincident,
    │                                a person who did not move)
    ├── NoOverlap                    two point clouds do not see the same surfaces
    ├── IcpUnavailable               open3d (ICP) does not import: not installed, or a system
    │                                library it links is missing
    └── CameraFileError              a camera calibration file (Qualisys, Pose2Sim, OpenCV)
                                     cannot be read: malformed, missing a field, not rigid

Every message says what was received and what to do about it, so the REST layer can pass it
through to the user unchanged.
"""

from __future__ import annotations


class CalibrationError(Exception):
    """Base class of calibration errors."""


class InvalidInput(CalibrationError):
    """The input arrays have the wrong shape or contain NaN/inf where numbers are required."""


class NotEnoughCorrespondences(CalibrationError):
    """Fewer corresponding points (or usable skeleton frames) than the method needs."""


class DegenerateGeometry(CalibrationError):
    """The correspondences exist but cannot determine a rigid pose (e.g. they are collinear)."""


class NoOverlap(CalibrationError):
    """Two point clouds share (almost) no surface at the initial guess."""


class IcpUnavailable(CalibrationError):
    """open3d, which ICP refinement needs, does not import; the message names what is missing."""


class CameraFileError(CalibrationError):
    """A camera calibration file cannot be imported; the message names the file and the field."""
