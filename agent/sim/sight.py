"""What a depth sensor can see of the virtual performers: field of view, range, occlusion, yaw.

Shared by every simulated sensor error model (:mod:`agent.sim.kinect_model`,
:mod:`agent.sim.tracker_model`): the geometry is the same whatever the tracker then gets wrong.

- Field of view and range: a joint is in view inside the horizontal × vertical field of view
  and between the near and far range.
- A body is reported only when its trunk is in view (two of the three spine joints, and at least
  40 % of all joints).
- Occlusion: the sight line to each joint is tested against capsules (segment + radius) around
  the trunk, head and limbs of every person; a joint is hidden when a capsule it does not belong
  to crosses its sight line. :func:`sight_lines` also says where along the line the occluder
  begins (its near surface), for models that pull hidden joints towards it.
- Yaw: the signed angle about +Y from a person's facing direction to the sensor.

Frames: ``persons_sensor`` in the sensor's camera frame (+X sensor-left, +Y up, +Z forward,
metres; the sensor at the origin); ``joints_world`` in the world (+Y up, metres).
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, JointId

J = JointId
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

TRUNK: Final = (
    J.SPINE_BASE,
    J.SPINE_MID,
    J.NECK,
    J.HEAD,
    J.SPINE_SHOULDER,
    J.HIP_LEFT,
    J.HIP_RIGHT,
    J.SHOULDER_LEFT,
    J.SHOULDER_RIGHT,
)

# Capsules (segment + radius) standing for body volume when deciding occlusion.
CAPSULES: Final = (
    (J.SPINE_BASE, J.SPINE_SHOULDER, 0.13),
    (J.NECK, J.HEAD, 0.10),
    (J.SHOULDER_LEFT, J.ELBOW_LEFT, 0.05),
    (J.ELBOW_LEFT, J.WRIST_LEFT, 0.04),
    (J.SHOULDER_RIGHT, J.ELBOW_RIGHT, 0.05),
    (J.ELBOW_RIGHT, J.WRIST_RIGHT, 0.04),
    (J.HIP_LEFT, J.KNEE_LEFT, 0.07),
    (J.KNEE_LEFT, J.ANKLE_LEFT, 0.05),
    (J.HIP_RIGHT, J.KNEE_RIGHT, 0.07),
    (J.KNEE_RIGHT, J.ANKLE_RIGHT, 0.05),
)
_CAPSULE_A: Final = np.array([c[0] for c in CAPSULES])
_CAPSULE_B: Final = np.array([c[1] for c in CAPSULES])
_CAPSULE_R: Final = np.array([c[2] for c in CAPSULES])
# A joint is never hidden by a capsule it belongs to (it is on that capsule's surface).
_OWN_CAPSULE: Final = np.zeros((JOINT_COUNT, len(CAPSULES)), dtype=bool)
for _k, (_a, _b, _r) in enumerate(CAPSULES):
    _OWN_CAPSULE[_a, _k] = _OWN_CAPSULE[_b, _k] = True
# Trunk joints sit on the trunk capsule's surface facing the sensor or on its axis; they are
# hidden by one's own trunk only when seen from behind, which the mirror models cover.
for _j in TRUNK:
    _OWN_CAPSULE[_j, 0] = True
# Shorten each sight line by this much so a joint is not hidden by the flesh around it (m).
_FLESH_M: Final = 0.06


def in_view(
    persons_sensor: FloatArray,
    fov_horizontal_deg: float,
    fov_vertical_deg: float,
    min_range_m: float,
    max_range_m: float,
) -> BoolArray:
    """(P, 25) True where a joint of ``persons_sensor`` (P, 25, 3) is inside the view volume."""
    tan_h = math.tan(math.radians(fov_horizontal_deg / 2))
    tan_v = math.tan(math.radians(fov_vertical_deg / 2))
    z = persons_sensor[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        horizontal = np.abs(persons_sensor[..., 0]) <= z * tan_h
        vertical = np.abs(persons_sensor[..., 1]) <= z * tan_v
    distance = np.linalg.norm(persons_sensor, axis=-1)
    result: BoolArray = (
        horizontal & vertical & (distance >= min_range_m) & (distance <= max_range_m)
    )
    return result


def trunk_visible(joints_in_view: BoolArray) -> bool:
    """Whether a body with these (25,) in-view flags is reported at all."""
    trunk = joints_in_view[[J.SPINE_BASE, J.SPINE_MID, J.SPINE_SHOULDER]]
    return bool(trunk.sum() >= 2 and joints_in_view.mean() >= 0.4)


def sight_lines(persons_sensor: FloatArray) -> tuple[BoolArray, FloatArray]:
    """Which joints are hidden, and where along their sight line the occluder begins.

    Args:
        persons_sensor: (P, 25, 3) joints, sensor frame (the sensor at the origin), metres.

    Returns:
        hidden: (P, 25) True where the sight line to a joint passes through a body capsule it
        does not belong to. entry_m: (P, 25) distance (m) from the sensor to the near surface of
        the first capsule hiding the joint (closest approach minus the half chord); NaN where
        the joint is not hidden.
    """
    n_persons = persons_sensor.shape[0]
    targets = persons_sensor.reshape(-1, 3)  # (N, 3), sensor at the origin
    cap_a = persons_sensor[:, _CAPSULE_A].reshape(-1, 3)  # (C, 3)
    cap_b = persons_sensor[:, _CAPSULE_B].reshape(-1, 3)
    radius = np.tile(_CAPSULE_R, n_persons)
    length = np.linalg.norm(targets, axis=1, keepdims=True)
    ends = targets * np.clip(1.0 - _FLESH_M / np.maximum(length, 1e-6), 0.0, 1.0)
    dist, s = _segment_segment_distance(ends, cap_a, cap_b)  # (N, C) each
    own = np.zeros((n_persons * JOINT_COUNT, n_persons * len(CAPSULES)), dtype=bool)
    for person in range(n_persons):
        rows = slice(person * JOINT_COUNT, (person + 1) * JOINT_COUNT)
        cols = slice(person * len(CAPSULES), (person + 1) * len(CAPSULES))
        own[rows, cols] = _OWN_CAPSULE
    hiding = (dist < radius[None, :]) & ~own
    with np.errstate(invalid="ignore"):
        half_chord = np.sqrt(np.maximum(radius[None, :] ** 2 - dist**2, 0.0))
    entry = np.clip(s * np.linalg.norm(ends, axis=1, keepdims=True) - half_chord, 0.0, None)
    entry = np.where(hiding, entry, np.inf).min(axis=1)
    hidden: BoolArray = hiding.any(axis=1).reshape(n_persons, -1)
    entry_m: FloatArray = np.where(np.isfinite(entry), entry, np.nan).reshape(n_persons, -1)
    return hidden, entry_m


def facing_angle(joints_world: FloatArray, sensor_position: FloatArray) -> float:
    """Signed yaw (radians, (−π, π]) about +Y from a person's facing direction to the sensor.

    ``joints_world``: (25, 3) one person, metres; ``sensor_position``: (3,) world, metres.
    0: the person faces the sensor; ±π: their back is to it.
    """
    left = (joints_world[J.SHOULDER_LEFT] - joints_world[J.SHOULDER_RIGHT]) + (
        joints_world[J.HIP_LEFT] - joints_world[J.HIP_RIGHT]
    )
    facing = np.cross(left, [0.0, 1.0, 0.0])  # person's left × up = forward
    to_sensor = sensor_position - joints_world[J.SPINE_BASE]
    facing_yaw = math.atan2(facing[0], facing[2])
    sensor_yaw = math.atan2(to_sensor[0], to_sensor[2])
    return (sensor_yaw - facing_yaw + math.pi) % (2 * math.pi) - math.pi


def _segment_segment_distance(
    ends: FloatArray, cap_a: FloatArray, cap_b: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Distance between sight segments origin→``ends`` (N, 3) and capsule axes a→b (C, 3).

    Returns (N, C) distances and (N, C) the closest point's fraction ``s`` ∈ [0, 1] along each
    sight segment (the clamped closest-points method, vectorised).
    """
    d1 = ends[:, None, :]  # segment 1 is origin + s·d1, s in [0, 1]
    d2 = (cap_b - cap_a)[None, :, :]
    r = -cap_a[None, :, :]  # origin - a
    a = np.sum(d1 * d1, axis=-1)
    e = np.sum(d2 * d2, axis=-1)
    f = np.sum(d2 * r, axis=-1)
    c = np.sum(d1 * r, axis=-1)
    b = np.sum(d1 * d2, axis=-1)
    denom = a * e - b * b
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(denom > 1e-12, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = np.where(e > 1e-12, (b * s + f) / e, 0.0)
    t_clamped = np.clip(t, 0.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(
            t != t_clamped, np.clip((t_clamped * b - c) / np.maximum(a, 1e-12), 0.0, 1.0), s
        )
    closest1 = s[..., None] * d1
    closest2 = cap_a[None, :, :] + t_clamped[..., None] * d2
    distance: FloatArray = np.linalg.norm(closest1 - closest2, axis=-1)
    fraction: FloatArray = np.asarray(s, dtype=np.float64)
    return distance, fraction
