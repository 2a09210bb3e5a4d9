"""Depth re-projection into a level reference camera (report B's B), and joints back out of it.

A head-mounted depth camera pitches and rolls with its wearer; a body tracker expects a camera
that stands level. :func:`level_reference` keeps the sensor's position and heading only (a
rotation about world +Y), :func:`reproject_depth` re-renders the depth and IR images as that
level camera (same intrinsics) would see them, and :func:`joints_to_sensor` /
:func:`joints_to_world` map the joints the tracker finds in the reference camera back.

Hole filling: the source pixels are a mesh (two triangles per 2×2 block, joined only where
their depths differ by less than 10 cm so person and background are never bridged) drawn
together with the points themselves, z-buffered (:mod:`skelfuse.agent.reproject_raster`); a
lone pixel the sensor dropped is covered from its neighbours under the same rule. On the
simulator's ray caster at ±10–20° pitch and roll with 2 % dropout: points alone leave 3–13 %
of the person's silhouette as holes, mesh plus points 0.5–1.3 % (1.8–3.5 % before dropouts
were filled), below the level camera's own 1.9–2.2 % (bench/moving/reprojection.py).

Frames and pixels are those of :mod:`skelfuse.agent.sim.depth_camera` (Kinect camera frame:
+X sensor-left, +Y up, +Z forward, metres; depth is Z, 0 = no reading). The world is +Y up.
Pure functions on arrays, numpy (+ numba when installed): importable on a sensor PC.
"""

from __future__ import annotations

from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.reproject_raster import project_loop, raster_loop, raster_numpy
from skelfuse.agent.sim.depth_camera import DepthIntrinsics
from skelfuse.jit import numba_module
from skelfuse.protocol.transform import apply, invert, pose_from_position_yaw_pitch

FloatArray = npt.NDArray[np.float64]

MAX_EDGE_M: Final = 0.10
"""Neighbouring pixels are joined by a triangle only when their depths differ by less."""


def level_reference(
    T_world_from_sensor: npt.ArrayLike, height_m: float | None = None
) -> FloatArray:
    """The level reference camera of a sensor pose: same floor position, same heading, no
    pitch or roll.

    Args:
        T_world_from_sensor: (4, 4) the sensor's pose (Kinect camera frame → world, +Y up).
        height_m: the reference's height above the floor (world y); None keeps the sensor's
            (no parallax: the image is only turned). A fixed height keeps the tracker's camera
            steady while the head bobs, at the cost of parallax (disoccluded holes).

    Returns:
        (4, 4) ``T_world_from_ref``: the sensor's floor position (x, z), optical axis
        horizontal along the sensor's heading (its forward axis projected onto the floor; when
        it looks straight up or down, its up axis, or down axis, projected instead), image rows
        level.

    Raises:
        ValueError: when the pose is not (4, 4).
    """
    pose = np.asarray(T_world_from_sensor, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"T_world_from_sensor must be (4, 4), not {pose.shape}")
    forward = pose[:3, 2]
    if np.hypot(forward[0], forward[2]) < 1e-6:
        # Looking straight down, the image's top points the way the wearer faces (up: its bottom).
        forward = pose[:3, 1] * (1.0 if forward[1] < 0 else -1.0)
    yaw = float(np.degrees(np.arctan2(forward[0], forward[2])))
    height = float(pose[1, 3]) if height_m is None else float(height_m)
    position = (float(pose[0, 3]), height, float(pose[2, 3]))
    return pose_from_position_yaw_pitch(position, yaw)


def reference_from_sensor(T_world_from_sensor: npt.ArrayLike) -> FloatArray:
    """(4, 4) ``T_ref_from_sensor`` for :func:`reproject_depth`: sensor frame → its level
    reference camera's frame (:func:`level_reference`)."""
    pose = np.asarray(T_world_from_sensor, dtype=np.float64)
    return invert(level_reference(pose)) @ pose


def joints_to_sensor(joints_ref: npt.ArrayLike, T_ref_from_sensor: npt.ArrayLike) -> FloatArray:
    """Joints found in the reference camera, in the sensor's own camera frame.

    Args:
        joints_ref: (..., 3) points, reference camera frame, metres (NaN stays NaN).
        T_ref_from_sensor: (4, 4) the transform the image was re-projected with.

    Returns:
        (..., 3) the same points, sensor camera frame.
    """
    return apply(invert(np.asarray(T_ref_from_sensor, dtype=np.float64)), joints_ref)


def joints_to_world(joints_ref: npt.ArrayLike, T_world_from_sensor: npt.ArrayLike) -> FloatArray:
    """Joints found in the reference camera of a sensor pose, in the world.

    Args:
        joints_ref: (..., 3) points, reference camera frame of :func:`level_reference`
            (``T_world_from_sensor``), metres (NaN stays NaN).
        T_world_from_sensor: (4, 4) the sensor's pose at the frame's capture time.

    Returns:
        (..., 3) world points, metres.
    """
    return apply(level_reference(T_world_from_sensor), joints_ref)


def reproject_depth(
    depth: npt.ArrayLike,
    ir: npt.ArrayLike,
    intrinsics: DepthIntrinsics,
    T_ref_from_sensor: npt.ArrayLike,
    max_edge_m: float = MAX_EDGE_M,
    compiled: bool | None = None,
) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """Re-render a depth image and its IR image as the reference camera sees them.

    Args:
        depth: (H, W) uint16 millimetres, or float metres; 0 (or non-finite) = no reading.
        ir: (H, W) IR intensities, any real dtype.
        intrinsics: the camera's (shared by sensor and reference: same image size).
        T_ref_from_sensor: (4, 4) sensor frame → reference frame (:func:`reference_from_sensor`).
        max_edge_m: source depth difference at or above which neighbours are not joined.
        compiled: use the numba loop (True), the numpy one (False), or numba when installed
            (None). The first compiled call compiles (or loads numba's disk cache): call
            :func:`skelfuse.agent.reproject_raster.warm_up` before the first frame.

    Returns:
        ``(depth_ref, ir_ref)``: (H, W) each; depth in the input's unit and dtype (float input
        gives float32 metres), 0 = nothing seen; IR in the input's dtype, 0 where no depth.

    Raises:
        ValueError: on shapes that disagree with each other or with the intrinsics.
    """
    image = np.asarray(depth)
    infra = np.asarray(ir)
    shape = (intrinsics.height, intrinsics.width)
    if image.shape != shape or infra.shape != shape:
        raise ValueError(
            f"depth {image.shape} and ir {infra.shape} must both be {shape} (the intrinsics)"
        )
    transform = np.asarray(T_ref_from_sensor, dtype=np.float64)
    if transform.shape != (4, 4):
        raise ValueError(f"T_ref_from_sensor must be (4, 4), not {transform.shape}")
    millimetres = np.issubdtype(image.dtype, np.integer)
    z = image.astype(np.float64) / (1000.0 if millimetres else 1.0)
    use_loop = numba_module() is not None if compiled is None else compiled
    if use_loop:
        u, v, safe = np.empty(shape), np.empty(shape), np.empty(shape)
        valid = np.empty(shape, dtype=bool)
        camera = np.array([intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy])
        project_loop(z, camera, transform, u, v, safe, valid)
    else:
        z, u, v, safe, valid = _project(z, intrinsics, transform)
    out_z = np.full(shape, np.inf)
    out_ir = np.zeros(shape)
    raster = raster_loop if use_loop else raster_numpy
    raster(u, v, safe, infra.astype(np.float64), valid, z, float(max_edge_m), out_z, out_ir)
    seen = np.isfinite(out_z)
    ir_out = np.where(seen, out_ir, 0.0)
    if np.issubdtype(infra.dtype, np.integer):
        limits = np.iinfo(infra.dtype)
        ir_out = np.clip(np.rint(ir_out), limits.min, limits.max)
    ir_ref = ir_out.astype(infra.dtype)
    if millimetres:
        limit = np.iinfo(image.dtype).max
        depth_ref = np.where(seen, np.clip(np.rint(out_z * 1000.0), 0, limit), 0).astype(
            image.dtype
        )
        return depth_ref, ir_ref
    return np.where(seen, out_z, 0.0).astype(np.float32), ir_ref


def _project(
    z: FloatArray, intrinsics: DepthIntrinsics, transform: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """:func:`skelfuse.agent.reproject_raster.project_loop` in numpy: the cleaned source depth,
    u, v (pixels), z (metres, 1 where not valid) in the reference camera, and validity."""
    has = np.isfinite(z) & (z > 0)
    z = np.where(has, z, 0.0)
    rows, cols = np.indices(z.shape, dtype=np.float64)
    x = -(cols - intrinsics.cx) * z / intrinsics.fx
    y = -(rows - intrinsics.cy) * z / intrinsics.fy
    rot, shift = transform[:3, :3], transform[:3, 3]
    xr = rot[0, 0] * x + rot[0, 1] * y + rot[0, 2] * z + shift[0]
    yr = rot[1, 0] * x + rot[1, 1] * y + rot[1, 2] * z + shift[1]
    zr = rot[2, 0] * x + rot[2, 1] * y + rot[2, 2] * z + shift[2]
    valid = has & (zr > 1e-3)
    safe = np.where(valid, zr, 1.0)
    u = np.where(valid, intrinsics.cx - intrinsics.fx * xr / safe, 0.0)
    v = np.where(valid, intrinsics.cy - intrinsics.fy * yr / safe, 0.0)
    return z, u, v, safe, valid
