"""What fusion works on and gives out: one sensor's body at an instant, one fused person.

Shapes: 25 joints (Kinect v2 order, :mod:`skelfuse.protocol.skeleton`); metres, world frame
(right-handed, +Y up, floor at y = 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class View:
    """One sensor's body at the fusion instant.

    joints_world: (25, 3) float64, metres, world frame, NaN where NotTracked.
    states: (25,) uint8 TrackingState.
    sensor_position: (3,) float64, where the sensor stands in the world (metres), if known.
    sensor_type: what the sensor's agent announced (``protocol.wire.SENSOR_TYPES``); selects
        the view's :class:`fusion.priors.SensorPrior`.
    """

    sensor_id: str
    tracking_id: int
    joints_world: FloatArray
    states: npt.NDArray[np.uint8]
    sensor_position: FloatArray | None = None
    sensor_type: str = "kinect_v2"


@dataclass(frozen=True, slots=True)
class FusedPerson:
    """One person's fused skeleton (world frame, metres; NaN and confidence 0 where unknown).

    joint_sources: (25,) int64 bitmask per joint: bit k set when ``sources[k]`` contributed at
        least 5 % of that joint's weight.
    mirrored: the sensors whose view of this person was swapped back (left ↔ right).
    """

    person_id: int
    joints: FloatArray
    confidence: FloatArray
    sources: tuple[str, ...]
    views: tuple[View, ...]
    joint_sources: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros(JOINT_COUNT, dtype=np.int64)
    )
    mirrored: tuple[str, ...] = ()
