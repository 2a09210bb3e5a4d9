"""Steps 1–2 of the fusion step for every sensor at once: bodies at the instant, in the world.

:func:`views_at` gives the same views, to the bit, as interpolating each sensor's bodies with
:func:`~skelfuse.fusion.sensors.body_arrays_at` and moving them with
:func:`~skelfuse.protocol.transform.apply`, sensor by sensor; it does the array work of all
sensors in a few calls instead of a dozen per sensor, which is what a step with many sensors
spends its time on:

- the usual interpolation (every body in both frames, in the same order) of all sensors is one
  element-wise pass: ``(1 − α)·a + α·b`` with each sensor's own ``α`` per row, the same IEEE
  operations as one sensor alone, and the same rule where a frame misses a joint; a sensor
  whose bodies came, went or changed order takes
  :func:`~skelfuse.fusion.sensors.body_arrays_at` as before;
- the move to the world frame is one element-wise pass over every row with its own sensor's
  pose, each coordinate ``((x·r₀ + y·r₁) + z·r₂) + t`` as ``apply`` computes it body by body
  (tests/unit/test_world_views.py checks the bits); with the compiled kernels, one loop does
  both (:mod:`skelfuse.fusion.kernels_lerp`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_lerp
from skelfuse.fusion.moving import world_position
from skelfuse.fusion.points import finite_points
from skelfuse.fusion.sensors import BodyArrays, SensorState, TimedFrame, body_arrays_at
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import TrackingState
from skelfuse.protocol.transform import Matrix4

FloatArray = npt.NDArray[np.float64]
PoseLookup = Callable[[str], Matrix4 | None]
"""A sensor's ``T_world_from_sensor`` (4×4, metres), or None while it is uncalibrated."""


class _Pending(NamedTuple):
    """An interpolation left for the batch: every body of ``nearer`` is in both frames, in the
    same order; ``first``/``second`` are the earlier and the later frame's bodies."""

    nearer: BodyArrays
    first: BodyArrays
    second: BodyArrays
    alpha: float


class SensorBodies(NamedTuple):
    """One sensor's bodies at an instant: the sensor, its pose (``T_world_from_sensor``, a
    moving sensor's ``T_world_from_space``), the bodies in its own frame (interpolated to the
    instant) and the same joints in the world, (B, 25, 3) float64 metres, NaN where unknown."""

    sensor: SensorState
    pose: Matrix4
    bodies: BodyArrays
    world: FloatArray


StackedRows = tuple[FloatArray, npt.NDArray[np.uint8]]
"""Bodies' world joints (N, 25, 3) float64 metres and their states (N, 25), stacked."""

Gathered = list[tuple[SensorState, Matrix4, BodyArrays | _Pending]]
"""What :func:`gather_at` finds of each sensor at one instant, before the array work."""


def views_at(
    sensors: Iterable[SensorState],
    pose_of: PoseLookup,
    t_s: float,
    gap_s: float,
) -> list[View]:
    """Every connected, calibrated sensor's bodies at ``t_s``, in the world frame.

    Args:
        sensors: the sensors' frame buffers (times on the server clock).
        pose_of: each sensor's ``T_world_from_sensor`` (4×4, metres); None leaves it out. A
            moving sensor's frames are in its tracking space (:mod:`skelfuse.fusion.moving`):
            its pose is ``T_world_from_space`` and its views' ``sensor_position`` is where its
            frames' poses put it at ``t_s``.
        t_s: the instant, server clock, seconds.
        gap_s: frames further apart than this are not interpolated between.

    Returns:
        One view per body, sensor by sensor in ``sensors``' order, bodies in the nearer frame's
        order; joints (25, 3) float64 world metres, NaN where unknown.
    """
    (bodies,) = resolve([gather_at(sensors, pose_of, t_s, gap_s)])
    return views_of(bodies, t_s)


def gather_at(
    sensors: Iterable[SensorState], pose_of: PoseLookup, t_s: float, gap_s: float
) -> Gathered:
    """The connected, calibrated sensors with a body at ``t_s`` (seconds, server clock), in
    ``sensors``' order, each with its pose and its bodies there or what :func:`resolve`
    interpolates them from (frames further apart than ``gap_s`` are not interpolated between)."""
    used: Gathered = []
    for sensor in sensors:
        if not sensor.connected:
            continue
        pose = pose_of(sensor.sensor_id)
        if pose is None:
            continue
        max_age = 1.5 / max(sensor.nominal_fps, 1.0)
        bodies = _bodies_or_pending(sensor.frames, t_s, gap_s, max_age)
        if bodies is None:
            continue
        if not (bodies.nearer if isinstance(bodies, _Pending) else bodies).tracking_ids:
            continue
        used.append((sensor, pose, bodies))
    return used


def resolve(groups: list[Gathered]) -> list[list[SensorBodies]]:
    """Each group's bodies interpolated and moved to the world: every group's rows in one
    interpolation pass and one move (rows are computed alone: the same bits as group by group,
    or sensor by sensor)."""
    return resolve_with_rows(groups)[0]


def resolve_with_rows(
    groups: list[Gathered],
) -> tuple[list[list[SensorBodies]], StackedRows | None]:
    """:func:`resolve`, and with the compiled kernels its rows as computed: every body's world
    joints (N, 25, 3) float64 and states (N, 25), group after group and sensor after sensor
    (the arrays each :class:`SensorBodies`' ``world`` and states are the rows of, or hold
    the same values); None from numpy, which computes them apart."""
    flat = [entry for group in groups for entry in group]
    if not flat:
        return [[] for _ in groups], None
    items = [bodies for _, _, bodies in flat]
    poses = [pose for _, pose, _ in flat]
    compiled = _compiled(items, poses) if kernels.enabled() and kernels_lerp.warmed() else None
    rows: StackedRows | None = None
    if compiled is None:
        arrays = _interpolate_pending(items)
        done = arrays, bodies_to_world(poses, [a.joints_m for a in arrays])
    else:
        done, rows = compiled
    resolved = [
        SensorBodies(sensor, pose, bodies, world)
        for (sensor, pose, _), bodies, world in zip(flat, *done, strict=True)
    ]
    out: list[list[SensorBodies]] = []
    lo = 0
    for group in groups:
        out.append(resolved[lo : lo + len(group)])
        lo += len(group)
    return out, rows


def _compiled(
    items: list[BodyArrays | _Pending], poses: list[Matrix4]
) -> tuple[tuple[list[BodyArrays], list[FloatArray]], StackedRows] | None:
    """:func:`_interpolate_pending` then :func:`bodies_to_world`, in one compiled loop
    (:func:`~skelfuse.fusion.kernels_lerp.to_world`, the same bits), and every row's world
    joints and states in one array each; None when a body is not float32 (frames hold
    float32; one from elsewhere takes numpy)."""
    firsts: list[npt.NDArray[np.float32]] = []
    seconds: list[npt.NDArray[np.float32]] = []
    first_states: list[npt.NDArray[np.uint8]] = []
    second_states: list[npt.NDArray[np.uint8]] = []
    alphas: list[float] = []
    counts: list[int] = []
    for item in items:
        if isinstance(item, _Pending):
            first, second, alpha = item.first, item.second, item.alpha
        else:  # as it is: the loop copies it (its second and α unread)
            first, second, alpha = item, item, -1.0
        firsts.append(first.joints_m)
        seconds.append(second.joints_m)
        first_states.append(first.states)
        second_states.append(second.states)
        alphas.append(alpha)
        counts.append(len(first.tracking_ids))
    a, b = np.concatenate(firsts), np.concatenate(seconds)
    if not a.dtype == b.dtype == np.float32:
        return None
    row_alphas = np.array(alphas).repeat(counts)  # the method: np.repeat's wrapper costs more
    joints32, states, world = kernels_lerp.to_world(
        a,
        b,
        np.concatenate(first_states),
        np.concatenate(second_states),
        row_alphas,
        row_alphas >= 0.0,
        np.arange(len(items)).repeat(counts),
        np.array(poses, dtype=np.float64),
    )
    done = _split(items, joints32, states, every_row=True), _rows_of(world, counts)
    return done, (world, states)


def views_of(bodies: list[SensorBodies], t_s: float) -> list[View]:
    """One view per body at the instant ``t_s`` (seconds), sensor by sensor (a moving sensor
    stands where its frames' poses put it at ``t_s``)."""
    views: list[View] = []
    for sensor, pose, arrays, world in bodies:
        position: FloatArray | None = pose[:3, 3]
        sensor_id, sensor_type = sensor.sensor_id, sensor.sensor_type
        if sensor.moving:  # its frames are in its space; it stands where its poses say at t_s
            position = world_position(sensor.frames, t_s, pose)
        hands = arrays.hands or [None] * len(arrays.tracking_ids)
        views.extend(
            View(sensor_id, tracking_id, body, states, position, sensor_type, hand)
            for tracking_id, body, states, hand in zip(
                arrays.tracking_ids, world, arrays.states, hands, strict=True
            )
        )
    return views


def _bodies_or_pending(
    frames: deque[TimedFrame] | list[TimedFrame], t_s: float, gap_s: float, max_age_s: float
) -> BodyArrays | _Pending | None:
    """:func:`body_arrays_at`'s answer, or, for its usual interpolation, what it would
    interpolate (left for :func:`_interpolate_pending`)."""
    buffer = frames
    index = len(buffer)
    while index > 0 and buffer[index - 1].t_server_s >= t_s:
        index -= 1
    if index == len(buffer) or index == 0 or buffer[index].t_server_s == t_s:
        return body_arrays_at(buffer, t_s, gap_s, max_age_s)  # no interpolation
    before, after = buffer[index - 1], buffer[index]
    gap = after.t_server_s - before.t_server_s
    if gap > gap_s or gap <= 0:
        return body_arrays_at(buffer, t_s, gap_s, max_age_s)
    alpha = (t_s - before.t_server_s) / gap
    first, second = before.arrays(), after.arrays()
    if first.tracking_ids != second.tracking_ids or not first.tracking_ids:
        return body_arrays_at(buffer, t_s, gap_s, max_age_s)  # bodies came, went or moved
    return _Pending(second if alpha >= 0.5 else first, first, second, alpha)


def _interpolate_pending(items: list[BodyArrays | _Pending]) -> list[BodyArrays]:
    """Every pending interpolation done, all sensors' rows in one pass: :func:`_lerp`'s rule
    and arithmetic element by element, with each row's own ``α`` (its sensor's); numpy's
    (:func:`_compiled` is the loop)."""
    pending = [item for item in items if isinstance(item, _Pending)]
    if not pending:
        return [item for item in items if isinstance(item, BodyArrays)]
    counts = [len(item.nearer.tracking_ids) for item in pending]
    first_states = np.concatenate([item.first.states for item in pending])
    second_states = np.concatenate([item.second.states for item in pending])
    alphas = np.repeat(np.array([item.alpha for item in pending]), counts)
    first = np.concatenate([item.first.joints_m for item in pending])
    second = np.concatenate([item.second.joints_m for item in pending])
    a = first.astype(np.float64)
    b = second.astype(np.float64)
    alpha = alphas[:, None, None]
    joints = (1.0 - alpha) * a + alpha * b
    states = np.minimum(first_states, second_states)
    # Finite only if every position of both frames is (NaN and inf propagate): the usual case
    # needs nothing more. Otherwise _lerp's rule for the rows that need it, which leaves every
    # row whose positions are all known as it is: where only one frame has a joint, the
    # nearer frame decides, position and state.
    if not math.isfinite(joints.sum()):
        missing = ~(finite_points(a) & finite_points(b))  # (N, 25)
        later = alpha[:, :, 0] >= 0.5  # (N, 1): the later frame is the nearer
        joints = np.where(missing[..., None], np.where(later[..., None], b, a), joints)
        states = np.where(missing, np.where(later, second_states, first_states), states)
        states[~finite_points(joints)] = TrackingState.NOT_TRACKED
    return _split(items, joints.astype(np.float32), states)


def _split(
    items: list[BodyArrays | _Pending],
    joints32: npt.NDArray[np.float32],
    states: npt.NDArray[np.uint8],
    every_row: bool = False,
) -> list[BodyArrays]:
    """``items`` with each pending one replaced by its rows of the interpolated ``joints32``
    (N, 25, 3) and ``states`` (N, 25), in order; rows for the pending items only, or with
    ``every_row`` for every item (the others' rows unread)."""
    done: list[BodyArrays] = []
    lo = 0
    for item in items:
        if isinstance(item, _Pending):
            hi = lo + len(item.nearer.tracking_ids)
            nearer = item.nearer
            done.append(
                BodyArrays(nearer.tracking_ids, joints32[lo:hi], states[lo:hi], nearer.hands)
            )
            lo = hi
        else:
            done.append(item)
            lo += len(item.tracking_ids) if every_row else 0
    return done


def _rows_of(array: FloatArray, counts: list[int]) -> list[FloatArray]:
    """``array``'s consecutive rows, ``counts[k]`` of them for the k-th part."""
    out: list[FloatArray] = []
    lo = 0
    for count in counts:
        out.append(array[lo : lo + count])
        lo += count
    return out


def bodies_to_world(
    poses: list[Matrix4], joints: list[npt.NDArray[np.float32]]
) -> list[FloatArray]:
    """Each sensor's (B, 25, 3) joints moved by its pose: ``apply(pose, joints)``'s floats
    (each coordinate ``((x·r₀ + y·r₁) + z·r₂) + t``), every row at once with its own pose."""
    counts = [len(rows) for rows in joints]
    points = np.concatenate(joints, dtype=np.float64)
    stacked = np.array(poses, dtype=np.float64)[np.repeat(np.arange(len(poses)), counts)]
    rotation, shift = stacked[:, None, :3, :3], stacked[:, None, :3, 3]  # (N, 1, 3, 3), (N, 1, 3)
    world = (
        (points[..., 0:1] * rotation[..., 0] + points[..., 1:2] * rotation[..., 1])
        + points[..., 2:3] * rotation[..., 2]
        + shift
    )
    return _rows_of(world, counts)
