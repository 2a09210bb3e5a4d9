"""How each tracked person is moving, per joint, as the late-sensor predictor reads it.

Under the ``deadline`` alignment a late sensor's newest frame is carried forward to the instant
(:mod:`skelfuse.fusion.extrapolation`). Its own two newest frames give a noisy velocity (the
difference of two noisy samples, divided by 33 ms); the person's temporal filter
(:mod:`skelfuse.fusion.filters`) has already estimated each joint's velocity, and acceleration,
from every sensor over many instants. This module reads that estimate from the pipeline's
per-person state, keyed by the (sensor, tracking id) bodies that were the person at the last
step, so that a late body can be moved by its own person's motion.

World frame, metres, seconds; nothing here changes the pipeline's state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.filters import JointFilter, KalmanState, OneEuroFilter
from skelfuse.fusion.identity import ViewKey
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.protocol.skeleton import MIRROR_PERMUTATION

FloatArray = npt.NDArray[np.float64]
_MIRROR = np.array(MIRROR_PERMUTATION)


@dataclass(frozen=True, slots=True)
class PersonMotion:
    """One person's filtered motion, in some body's joint order.

    velocity: (25, 3) m/s, world frame (NaN where the filter has no estimate).
    acceleration: (25, 3) m/s² (zeros for a filter without one).
    t_s: (25, 3) the time each coordinate's estimate holds at (server clock, seconds).
    """

    velocity: FloatArray
    acceleration: FloatArray
    t_s: FloatArray

    def displacement(self, from_s: float, to_s: float) -> FloatArray:
        """How far each joint moves from ``from_s`` to ``to_s`` (seconds, server clock):
        ``v·Δt + a/2·((to − t)² − (from − t)²)``, constant acceleration from the estimate's
        time ``t``. (25, 3) metres, NaN where unknown."""
        # A coordinate never seen has t = −inf (and a NaN velocity): no inf − inf warning.
        t = np.where(np.isfinite(self.t_s), self.t_s, from_s)
        squares = (to_s - t) ** 2 - (from_s - t) ** 2
        moved: FloatArray = self.velocity * (to_s - from_s) + 0.5 * self.acceleration * squares
        return moved

    def without_acceleration(self) -> PersonMotion:
        """The same velocity, acceleration taken as zero (``v·Δt`` only)."""
        return PersonMotion(self.velocity, np.zeros_like(self.acceleration), self.t_s)

    def mirrored(self) -> PersonMotion:
        """The same motion with left and right joints swapped (for a mirrored view's order)."""
        return PersonMotion(self.velocity[_MIRROR], self.acceleration[_MIRROR], self.t_s[_MIRROR])


def filter_motion(joint_filter: JointFilter) -> PersonMotion | None:
    """The velocity (and acceleration) a started filter estimates, or None for a filter that
    keeps none (``filter = "none"``) or has not seen a sample yet.

    Reads the Kalman filters' state (position, velocity[, acceleration] per coordinate) and One
    Euro's smoothed derivative; a coordinate never seen is NaN in the filter, so here too.
    """
    if isinstance(joint_filter, KalmanState):
        if joint_filter._x is None or joint_filter._t is None:
            return None
        x, t = joint_filter._x, joint_filter._t
        acceleration = x[..., 2] if x.shape[-1] > 2 else np.zeros(x.shape[:-1])
        return PersonMotion(x[..., 1].copy(), acceleration.copy(), t.copy())
    if isinstance(joint_filter, OneEuroFilter):
        if joint_filter._dx is None or joint_filter._t is None or joint_filter._x is None:
            return None
        velocity = np.where(np.isfinite(joint_filter._x), joint_filter._dx, np.nan)
        return PersonMotion(velocity, np.zeros_like(velocity), joint_filter._t.copy())
    return None


def track_motions(pipeline: FusionPipeline, accelerate: bool = True) -> dict[ViewKey, PersonMotion]:
    """Every body that was part of a person at the last step, with that person's motion in the
    body's own joint order (swapped when the pipeline swapped that view's left and right).

    Keys: (sensor id, the sensor's tracking id). Bodies of persons whose filter has no estimate
    (just born, or just turned over and restarted) are absent. With ``accelerate`` False the
    filters' acceleration is left out (velocity only).
    """
    out: dict[ViewKey, PersonMotion] = {}
    for person_id, track in pipeline.tracker.tracks.items():
        memory = pipeline.memories.get(person_id)
        if memory is None or not track.members:
            continue
        motion = filter_motion(memory.filter)
        if motion is None:
            continue
        if not accelerate:
            motion = motion.without_acceleration()
        swapped: PersonMotion | None = None
        for key in track.members:
            if memory.labels.get(key, False):
                swapped = motion.mirrored() if swapped is None else swapped
                out[key] = swapped
            else:
                out[key] = motion
    return out


def track_members(pipeline: FusionPipeline) -> dict[ViewKey, tuple[int, bool]]:
    """Every body that was part of a person at the last step: its person's id, and whether the
    pipeline swapped that view's left and right (its mirror label).

    Keys: (sensor id, the sensor's tracking id). Two bodies of one person with different labels
    have their left and right joints the other way round from each other.
    """
    out: dict[ViewKey, tuple[int, bool]] = {}
    for person_id, track in pipeline.tracker.tracks.items():
        memory = pipeline.memories.get(person_id)
        labels = memory.labels if memory is not None else {}
        for key in track.members:
            out[key] = (person_id, labels.get(key, False))
    return out
