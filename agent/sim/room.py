"""A simulated room seen by a Kinect v2-like depth camera (numpy only).

The calibration uses depth point clouds (ICP, floor fit). A simulated agent renders one on
request: the room (floor, four walls, a few furniture-like boxes) and the performers (capsules
around their bones) are ray cast from the sensor's pose into a 512×424 depth image, which the
camera model (:mod:`agent.sim.depth_camera`: pixel convention, Kinect v2-like noise and missing
pixels) turns into what the sensor reports, then back-projected into the sensor's camera frame.

Frames: the room and the performers are in the world (+Y up, metres, floor at y = 0); depth
images and point clouds are in the sensor's Kinect camera frame (+X sensor-LEFT, +Y up,
+Z forward, metres).

This module must stay importable on a sensor PC: numpy only, no scipy or open3d.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.depth_camera import (
    KINECT_V2_DEPTH,
    DepthIntrinsics,
    DepthNoise,
    depth_to_points,
    pixel_rays,
    sensor_effects,
    voxel_downsample,
)
from skelfuse.protocol.skeleton import JointId

J = JointId
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned box (furniture), world frame, metres: min and max corners."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Room:
    """Floor at y = 0 (±``floor_half_m`` in x and z), four walls at x, z = ±``wall_half_m`` up
    to ``wall_height_m`` (no ceiling), and furniture boxes standing on the floor."""

    wall_half_m: float = 4.0
    wall_height_m: float = 2.6
    floor_half_m: float = 5.0
    boxes: tuple[Box, ...] = field(default_factory=tuple)


def _box_on_floor(x: float, z: float, size_x: float, size_z: float, height: float) -> Box:
    return Box((x - size_x / 2, 0.0, z - size_z / 2), (x + size_x / 2, height, z + size_z / 2))


def default_room() -> Room:
    """The simulated room: 8 m × 8 m, walls 2.6 m high, six boxes of 0.45–1.2 m near the
    walls (the central 2 m × 2 m, where people walk, stays free)."""
    return Room(
        boxes=(
            _box_on_floor(-3.2, -2.0, 0.8, 0.6, 0.75),  # desk-like
            _box_on_floor(3.1, 2.4, 0.5, 1.0, 1.2),  # cabinet
            _box_on_floor(2.8, -3.1, 0.6, 0.6, 0.45),  # low box
            _box_on_floor(-2.4, 3.2, 1.2, 0.6, 0.9),  # sideboard
            _box_on_floor(0.6, -3.4, 0.5, 0.5, 1.1),  # shelf
            _box_on_floor(-3.4, 0.9, 0.4, 0.8, 0.6),  # crate
        )
    )


# Capsules (joint a, joint b, radius m) standing for the body surface; the trunk, head and limb
# radii match the occlusion capsules of agent.sim.kinect_model, plus hips, shoulders, feet, hands.
_BODY_CAPSULES: Final = (
    (J.SPINE_BASE, J.SPINE_SHOULDER, 0.13),
    (J.NECK, J.HEAD, 0.10),
    (J.SHOULDER_LEFT, J.SHOULDER_RIGHT, 0.06),
    (J.HIP_LEFT, J.HIP_RIGHT, 0.09),
    (J.SHOULDER_LEFT, J.ELBOW_LEFT, 0.05),
    (J.ELBOW_LEFT, J.WRIST_LEFT, 0.04),
    (J.WRIST_LEFT, J.HAND_LEFT, 0.04),
    (J.SHOULDER_RIGHT, J.ELBOW_RIGHT, 0.05),
    (J.ELBOW_RIGHT, J.WRIST_RIGHT, 0.04),
    (J.WRIST_RIGHT, J.HAND_RIGHT, 0.04),
    (J.HIP_LEFT, J.KNEE_LEFT, 0.07),
    (J.KNEE_LEFT, J.ANKLE_LEFT, 0.05),
    (J.ANKLE_LEFT, J.FOOT_LEFT, 0.04),
    (J.HIP_RIGHT, J.KNEE_RIGHT, 0.07),
    (J.KNEE_RIGHT, J.ANKLE_RIGHT, 0.05),
    (J.ANKLE_RIGHT, J.FOOT_RIGHT, 0.04),
)
_EPS: Final = 1e-6


def _hit_planes(
    room: Room, origin: FloatArray, dirs: FloatArray, t_best: FloatArray, normal: FloatArray
) -> None:
    """Floor and walls; updates ``t_best`` (N,) and ``normal`` (N, 3) in place."""
    half, top, floor_half = room.wall_half_m, room.wall_height_m, room.floor_half_m
    # (axis, plane coordinate, normal sign, limits on the other two axes)
    planes = [(1, 0.0, 1.0)]
    planes += [(0, -half, 1.0), (0, half, -1.0), (2, -half, 1.0), (2, half, -1.0)]
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, coord, sign in planes:
            t = (coord - origin[axis]) / dirs[:, axis]
            hit_point = origin + t[:, None] * dirs
            if axis == 1:
                inside = (np.abs(hit_point[:, 0]) <= floor_half) & (
                    np.abs(hit_point[:, 2]) <= floor_half
                )
            else:
                other = 2 if axis == 0 else 0
                inside = (
                    (hit_point[:, 1] >= 0.0)
                    & (hit_point[:, 1] <= top)
                    & (np.abs(hit_point[:, other]) <= half)
                )
            better = inside & (t > _EPS) & (t < t_best)
            t_best[better] = t[better]
            normal[better] = 0.0
            normal[better, axis] = sign


def _hit_boxes(
    room: Room, origin: FloatArray, dirs: FloatArray, t_best: FloatArray, normal: FloatArray
) -> None:
    """Axis-aligned boxes (slab method); a box containing the sensor is ignored."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
    for box in room.boxes:
        lo = np.asarray(box.min_m)
        hi = np.asarray(box.max_m)
        with np.errstate(invalid="ignore"):
            t1 = (lo - origin) * inv
            t2 = (hi - origin) * inv
        t_min = np.fmin(t1, t2)
        t_max = np.fmax(t1, t2)
        axis = np.argmax(t_min, axis=1)
        t_near = t_min[np.arange(len(dirs)), axis]
        t_far = t_max.min(axis=1)
        better = (t_near <= t_far) & (t_near > _EPS) & (t_near < t_best)
        if not better.any():
            continue
        t_best[better] = t_near[better]
        idx = np.flatnonzero(better)
        normal[idx] = 0.0
        normal[idx, axis[idx]] = -np.sign(dirs[idx, axis[idx]])


def _hit_person(
    joints: FloatArray, origin: FloatArray, dirs: FloatArray, t_best: FloatArray, normal: FloatArray
) -> None:
    """Capsules around one person's bones; ``dirs`` must be unit vectors here."""
    if not np.isfinite(joints).all():
        return
    centre = joints.mean(axis=0)
    radius = float(np.linalg.norm(joints - centre, axis=1).max()) + 0.15
    oc = origin - centre
    b = dirs @ oc
    c = float(oc @ oc) - radius**2
    candidates = np.flatnonzero(b * b - c > 0.0)
    if candidates.size == 0:
        return
    rd = dirs[candidates]
    t_cand = t_best[candidates].copy()
    n_cand = normal[candidates].copy()
    for joint_a, joint_b, r in _BODY_CAPSULES:
        a = joints[joint_a]
        ba = joints[joint_b] - a
        oa = origin - a
        baba = float(ba @ ba)
        bard = rd @ ba
        baoa = float(ba @ oa)
        rdoa = rd @ oa
        oaoa = float(oa @ oa)
        qa = baba - bard * bard
        qb = baba * rdoa - baoa * bard
        qc = baba * oaoa - baoa * baoa - r * r * baba
        h = qb * qb - qa * qc
        t = np.full(len(rd), np.inf)
        ok = (h >= 0.0) & (qa > 1e-12)
        with np.errstate(invalid="ignore", divide="ignore"):
            t_body = (-qb - np.sqrt(np.maximum(h, 0.0))) / qa
            y = baoa + t_body * bard
        body = ok & (y > 0.0) & (y < baba)
        t[body] = t_body[body]
        # End caps: spheres at a (y <= 0) or b (y >= baba).
        for end in (a, joints[joint_b]):
            oc_end = origin - end
            b_end = rd @ oc_end
            h_end = b_end * b_end - (float(oc_end @ oc_end) - r * r)
            t_end = -b_end - np.sqrt(np.maximum(h_end, 0.0))
            cap = (h_end > 0.0) & (t_end > _EPS) & (t_end < t)
            t[cap] = t_end[cap]
        better = (t > _EPS) & (t < t_cand)
        if not better.any():
            continue
        t_cand[better] = t[better]
        hit = origin + t[better, None] * rd[better]
        s = np.clip(((hit - a) @ ba) / max(baba, 1e-12), 0.0, 1.0)
        outward = hit - (a + s[:, None] * ba)
        n_cand[better] = outward / np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-9)
    t_best[candidates] = t_cand
    normal[candidates] = n_cand


def render_depth(
    room: Room,
    persons_world: npt.ArrayLike | None,
    T_world_from_sensor: npt.ArrayLike,
    intrinsics: DepthIntrinsics = KINECT_V2_DEPTH,
    rng: np.random.Generator | None = None,
    noise: DepthNoise | None = None,
) -> npt.NDArray[np.float32]:
    """Ray cast one depth image.

    Args:
        room: the static scene (world frame).
        persons_world: (P, 25, 3) joints of the people in the room (world, metres) or None.
        T_world_from_sensor: (4, 4) pose of the depth camera (Kinect camera frame → world).
        intrinsics: image size, focal lengths, range.
        rng: random generator for noise and dropout; None renders an ideal image (no noise,
            no random dropout; range, grazing-angle and edge losses still apply).
        noise: the depth error model (default :class:`DepthNoise`).

    Returns:
        (height, width) float32 depth (Z along the optical axis) in metres, 0 = no reading.
    """
    model = noise or DepthNoise()
    pose = np.asarray(T_world_from_sensor, dtype=np.float64)
    rays_cam = pixel_rays(intrinsics).reshape(-1, 3)
    ray_len = np.linalg.norm(rays_cam, axis=1)
    dirs = (rays_cam / ray_len[:, None]) @ pose[:3, :3].T  # unit, world frame
    origin = pose[:3, 3].copy()
    t_best = np.full(len(dirs), np.inf)
    normal = np.zeros_like(dirs)
    _hit_planes(room, origin, dirs, t_best, normal)
    _hit_boxes(room, origin, dirs, t_best, normal)
    if persons_world is not None:
        persons = np.asarray(persons_world, dtype=np.float64).reshape(-1, 25, 3)
        for joints in persons:
            _hit_person(joints, origin, dirs, t_best, normal)
    depth = t_best / ray_len  # unit-ray length → Z
    valid = np.isfinite(depth)
    cos_incidence = np.abs(np.sum(normal * dirs, axis=1))
    valid &= cos_incidence >= np.cos(np.radians(model.max_incidence_deg))
    depth = np.where(valid, depth, 0.0).reshape(intrinsics.height, intrinsics.width)
    return sensor_effects(depth, intrinsics, model, rng)


def capture_point_cloud(
    room: Room,
    persons_world: npt.ArrayLike | None,
    T_world_from_sensor: npt.ArrayLike,
    rng: np.random.Generator | None,
    intrinsics: DepthIntrinsics = KINECT_V2_DEPTH,
    voxel_m: float = 0.03,
    max_points: int = 20000,
) -> npt.NDArray[np.float32]:
    """What a simulated agent sends when the server asks for depth: one rendered frame,
    back-projected, voxel-averaged and capped.

    Returns:
        (N, 3) float32 points, N ≤ ``max_points``, Kinect camera frame, metres.
    """
    depth = render_depth(room, persons_world, T_world_from_sensor, intrinsics, rng)
    points = voxel_downsample(depth_to_points(depth, intrinsics), voxel_m)
    if len(points) > max_points:
        chooser = rng if rng is not None else np.random.default_rng(0)
        keep = np.sort(chooser.choice(len(points), size=max_points, replace=False))
        points = points[keep]
    return points
