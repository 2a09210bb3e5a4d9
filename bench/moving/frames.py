"""Report B's measure in simulation: erroneous frames of a head-mounted sensor (issue 15 item 5).

A wearer (person 0) turns their head by report B's schedule (:mod:`agent.sim.head_mounted`)
about one axis while their sensor films person 1 standing 2.5 m away (or both walk to and fro,
``walk_m``). Each frame's joints (the simulated Kinect v2 with its noise, in the sensor frame)
are placed in the world two ways:

- per-frame pose: with the pose the headset attached to that frame;
- fixed sensor: with the first frame's pose, held (what a server assuming a fixed sensor does).

A joint's frame is *erroneous* when its 3-D error exceeds the limb's width (:data:`WIDTHS_M`)
or it is missing (body not reported, joint out of view). Report B measured 2-D image distances
to markers on head, hands and ankles; here the truth is the simulator's joints and the distance
is 3-D, so these figures compare the two conditions, not the report's absolute numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.head_mounted import (
    Axis,
    HeadRig,
    PoseErrors,
    schedule_duration_s,
)
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.mutual import MutualCapture
from skelfuse.agent.sim.scenarios import RingWalkers
from skelfuse.protocol.sensor_pose import pose_matrix
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import Matrix4, apply

J = JointId

#: Report B's five markers as Kinect v2 joints, with the width (m) above which a frame is
#: erroneous: head breadth ~15.5 cm, hand breadth ~8.5 cm, ankle/foot breadth ~10 cm (adult
#: anthropometric means; report B names "a limb's width" without numbers).
WIDTHS_M: Final[dict[str, tuple[int, float]]] = {
    "head": (J.HEAD, 0.155),
    "left hand": (J.HAND_LEFT, 0.085),
    "right hand": (J.HAND_RIGHT, 0.085),
    "left foot": (J.ANKLE_LEFT, 0.10),
    "right foot": (J.ANKLE_RIGHT, 0.10),
}
CONDITIONS: Final = ("fixed sensor", "per-frame pose")


@dataclass(frozen=True, slots=True)
class FrameCase:
    """One run: rotation axis, walking, sensor noise on/off, pose errors, seed, duration."""

    axis: Axis
    seed: int = 0
    walk_m: float = 0.0
    noisy_sensor: bool = True
    errors: PoseErrors = field(default_factory=PoseErrors)
    duration_s: float | None = None  # default: one pass of the schedule (9 s)
    fps: float = 30.0


def _quiet_params() -> KinectV2Params:
    """The Kinect model without its noise, bias, glitches, dropouts or facing bias."""
    return KinectV2Params(
        jitter_base_m=0.0,
        jitter_per_m2=0.0,
        bias_trunk_m=0.0,
        bias_limb_m=0.0,
        bias_extremity_m=0.0,
        inferred_error_m=0.0,
        facing_bias=0.0,
        glitch_rate_hz=0.0,
        dropout_rate_hz=0.0,
    )


def erroneous_frames(case: FrameCase) -> dict[str, dict[str, float]]:
    """Per condition (:data:`CONDITIONS`), per marker (:data:`WIDTHS_M`): % of frames
    erroneous, and ``"<marker> missing"``: % of frames without the joint (in both conditions)."""
    capture = MutualCapture(
        RingWalkers(2, 1.25, walk_m=case.walk_m),
        [HeadRig(axis=case.axis)],
        errors=case.errors,
        params=None if case.noisy_sensor else _quiet_params(),
        seed=case.seed,
    )
    duration = case.duration_s if case.duration_s is not None else schedule_duration_s()
    times = np.arange(round(duration * case.fps)) / case.fps
    joints = [j for j, _ in WIDTHS_M.values()]
    widths = np.array([w for _, w in WIDTHS_M.values()])
    errors = {c: np.full((len(times), len(joints)), np.inf) for c in CONDITIONS}
    held: Matrix4 | None = None
    for k, t in enumerate(times):
        frame = capture.frame(0, float(t))
        pose = pose_matrix(frame.pose)
        held = pose if held is None else held
        target = [b for b in frame.bodies if b.person == 1]
        if not target:
            continue
        truth = capture.truth(float(t))[1, joints]
        sensor_points = target[0].joints_m[joints].astype(np.float64)
        for condition, transform in zip(CONDITIONS, (held, pose), strict=True):
            distance = np.linalg.norm(apply(transform, sensor_points) - truth, axis=1)
            errors[condition][k] = np.where(np.isnan(distance), np.inf, distance)
    result: dict[str, dict[str, float]] = {}
    for condition in CONDITIONS:
        bad: npt.NDArray[np.bool_] = errors[condition] > widths[None, :]
        missing = np.isinf(errors[condition])
        row = {name: 100.0 * float(bad[:, i].mean()) for i, name in enumerate(WIDTHS_M)}
        row |= {f"{n} missing": 100.0 * float(missing[:, i].mean()) for i, n in enumerate(WIDTHS_M)}
        result[condition] = row
    return result


def reduction_percent(fixed: float, per_frame: float) -> float:
    """Report B's figure: how much the per-frame pose cuts erroneous frames, % (NaN if none)."""
    return float("nan") if fixed == 0 else 100.0 * (fixed - per_frame) / fixed
