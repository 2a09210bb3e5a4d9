"""The fused error of mutual capture as the pose-to-frame mismatch grows (issue 15 item 5).

Three wearers on a 1.5 m circle (2.6 m apart) walk to and fro along their radius (0.6 m every
6 s) and look at each other; each turns their head by report B's schedule about one axis (the
run's), the three 3 s apart in the schedule. Each wearer's simulated Kinect v2 reports the other
two; each frame carries the headset's pose of the instant ``t + mismatch``
(:class:`~skelfuse.agent.sim.head_mounted.PoseErrors`).

Two ways to fuse those frames:

- ``server``: the production :class:`~skelfuse.server.hub.FusionHub` fed the wire frames (bodies
  in the sensor frame, pose attached), the three sensors moving in one tracking space ``room``
  whose world transform is the identity; fused persons matched to the truth as the accuracy
  benchmark does (:class:`bench.accuracy.metrics.Log`). Needs the server's moving-sensor support.
- ``minimal``: NOT the server's fusion. The wearers capture at the same instants; every view of
  a person (association by the simulator's truth) is placed in the world with its frame's pose
  and the views are averaged joint by joint, weighted 1 (Tracked) / 0.2 (Inferred).

Errors: MPJPE (mean over joints seen and frames) and the per-joint median, mm.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.head_mounted import Axis, HeadRig, PoseErrors
from skelfuse.agent.sim.mutual import MutualCapture, WearerFrame
from skelfuse.agent.sim.scenarios import RingWalkers
from skelfuse.protocol.sensor_pose import pose_matrix
from skelfuse.protocol.skeleton import TrackingState
from skelfuse.protocol.transform import apply

FPS: Final = 30.0
MISMATCHES_MS: Final = (0.0, 10.0, 20.0, 50.0)
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class FusedCase:
    """One run: axis, mismatch, seed, wearers, walk, schedule speed, duration, pose noise."""

    axis: Axis
    mismatch_ms: float
    seed: int = 0
    wearers: int = 3
    walk_m: float = 0.6
    turn_speed: float = 1.0
    duration_s: float = 9.0
    position_noise_mm: float = 0.0
    rotation_noise_deg: float = 0.0

    def capture(self) -> MutualCapture:
        """The simulated scene of this case."""
        offset = 9.0 / max(self.wearers, 1)
        rigs = [
            HeadRig(axis=self.axis, schedule_offset_s=i * offset, turn_speed=self.turn_speed)
            for i in range(self.wearers)
        ]
        errors = PoseErrors(self.position_noise_mm, self.rotation_noise_deg, self.mismatch_ms)
        performer = RingWalkers(self.wearers, 1.5, walk_m=self.walk_m)
        return MutualCapture(performer, rigs, errors=errors, seed=self.seed)


def synchronous_frames(
    capture: MutualCapture, duration_s: float
) -> Iterator[tuple[float, list[WearerFrame]]]:
    """(t, every wearer's frame at t) at :data:`FPS`, all wearers capturing together."""
    for k in range(round(duration_s * FPS)):
        t = k / FPS
        yield t, [capture.frame(w, t) for w in range(capture.wearer_count)]


def minimal_fusion(frames: list[WearerFrame], person_count: int) -> FloatArray:
    """(P, 25, 3) each person's views placed with their frames' poses and averaged (NaN where no
    view sees a joint). Not the server's fusion: truth association, fixed weights."""
    total = np.zeros((person_count, 25, 3))
    weight = np.zeros((person_count, 25, 1))
    for frame in frames:
        transform = pose_matrix(frame.pose)
        for body in frame.bodies:
            points = apply(transform, body.joints_m.astype(np.float64))
            w = np.where(body.states == TrackingState.TRACKED, 1.0, 0.0)
            w = np.where(body.states == TrackingState.INFERRED, 0.2, w)[:, None]
            w = np.where(np.isfinite(points).all(axis=1, keepdims=True), w, 0.0)
            total[body.person] += np.nan_to_num(points) * w
            weight[body.person] += w
    with np.errstate(invalid="ignore", divide="ignore"):
        fused: FloatArray = np.where(weight > 0, total / weight, np.nan)
    return fused


def minimal_errors(case: FusedCase) -> dict[str, float]:
    """MPJPE and per-joint median (mm) and coverage of :func:`minimal_fusion` over a run."""
    capture = case.capture()
    errors: list[FloatArray] = []
    for t, frames in synchronous_frames(capture, case.duration_s):
        truth = capture.truth(t)
        fused = minimal_fusion(frames, truth.shape[0])
        errors.append(np.linalg.norm(fused - truth, axis=2))
    return summarise(np.stack(errors))


def summarise(errors: FloatArray) -> dict[str, float]:
    """``errors``: (frames, persons, 25) metres, NaN where unseen -> mm figures and coverage."""
    seen = errors[np.isfinite(errors)]
    if seen.size == 0:
        return {"mpjpe_mm": math.nan, "median_mm": math.nan, "coverage": 0.0}
    return {
        "mpjpe_mm": 1000.0 * float(seen.mean()),
        "median_mm": 1000.0 * float(np.median(seen)),
        "coverage": float(seen.size / errors.size),
    }
