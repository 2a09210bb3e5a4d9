"""Steps 1–2 of the fusion step for every sensor at once: bodies at the instant, in the world.

:func:`views_at` gives the same views, to the bit, as interpolating each sensor's bodies with
:func:`~skelfuse.fusion.sensors.body_arrays_at` and moving them with
:func:`~skelfuse.protocol.transform.apply`, sensor by sensor; it does the array work of all
sensors in a few calls instead of a dozen per sensor, which is what a step with many sensors
spends its time on:

- the usual interpolation (every body in both frames, in the same order) of all sensors is one
  pass: ``(1 − α)·a + α·b`` in float64 with each sensor's own ``α`` per row, float32 out, the
  same IEEE operations as one sensor alone, and the same rule where a frame misses a joint
  (the nearer frame decides, the lower tracking state wins); a sensor whose bodies came, went
  or changed order takes :func:`~skelfuse.fusion.sensors.body_arrays_at` as before;
- the move to the world frame is in the same pass, every row with its own sensor's pose, each
  coordinate ``((x·r₀ + y·r₁) + z·r₂) + t`` as ``apply`` computes it body by body
  (tests/unit/test_world_views.py checks the bits).

Both are one compiled loop over every row (:func:`to_world`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.sensors import (
    BodyArrays,
    SensorState,
    TimedFrame,
    body_arrays_at,
    world_position,
)
from skelfuse.fusion.views import View
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4

FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]
StateArray = npt.NDArray[np.uint8]
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
            moving sensor's frames are in its tracking space
            (:func:`skelfuse.fusion.sensors.placed_in_space`): its pose is ``T_world_from_space``
            and its views' ``sensor_position`` is where its frames' poses put it at ``t_s``.
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
    """:func:`resolve`, and its rows as computed: every body's world joints (N, 25, 3) float64
    and states (N, 25), group after group and sensor after sensor (the arrays each
    :class:`SensorBodies`' ``world`` and states are the rows of, or hold the same values);
    None without a body."""
    flat = [entry for group in groups for entry in group]
    if not flat:
        return [[] for _ in groups], None
    items = [bodies for _, _, bodies in flat]
    poses = [pose for _, pose, _ in flat]
    done, rows = _resolved_rows(items, poses)
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


def _resolved_rows(
    items: list[BodyArrays | _Pending], poses: list[Matrix4]
) -> tuple[tuple[list[BodyArrays], list[FloatArray]], StackedRows]:
    """Every pending interpolation done and every body moved to the world by its pose, in one
    call of :func:`to_world`: the items' bodies (a pending one replaced by its interpolated
    rows) and world joints, and every row's world joints and states in one array each."""
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
    if not a.dtype == b.dtype == np.float32:  # frames hold float32; a body from elsewhere:
        a, b = a.astype(np.float64), b.astype(np.float64)  # not rounded before the arithmetic
    row_alphas = np.array(alphas).repeat(counts)  # the method: np.repeat's wrapper costs more
    joints32, states, world = to_world(
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


_NOT_TRACKED = int(TrackingState.NOT_TRACKED)


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now, off any latency-bound path: for
    float32 bodies (every frame's) and float64 ones."""
    states = np.zeros((1, JOINT_COUNT), np.uint8)
    rows = (np.full(1, 0.5), np.ones(1, bool), np.zeros(1, np.intp))
    for dtype in (np.float32, np.float64):
        joints = np.zeros((1, JOINT_COUNT, 3), dtype)
        to_world(joints, joints, states, states, *rows, np.eye(4)[None])


def to_world(
    first: Float32Array | FloatArray,
    second: Float32Array | FloatArray,
    first_states: StateArray,
    second_states: StateArray,
    alpha: FloatArray,
    interpolate: npt.NDArray[np.bool_],
    pose_of_row: npt.NDArray[np.intp],
    poses: FloatArray,
) -> tuple[Float32Array, StateArray, FloatArray]:
    """Every row interpolated (where ``interpolate``) and moved to the world by its pose.

    Args:
        first, second: (N, 25, 3) float32 (or both float64) metres, the earlier and the later
            frame's bodies;
        first_states, second_states: (N, 25) their tracking states; alpha: (N,) each row's
            fraction (its sensor's), in [0, 1]; a row not to interpolate is ``first`` as it
            is (``second`` and ``alpha`` unread);
        interpolate: (N,) which rows to interpolate; pose_of_row: (N,) each row's pose;
        poses: (S, 4, 4) ``T_world_from_sensor`` (metres).

    Returns:
        (N, 25, 3) float32 joints and (N, 25) states: where both frames have a joint (all
        three coordinates finite) the float64 interpolation rounded to float32 and the lower
        state; elsewhere the nearer frame's joint and state (the later one from α = 0.5); a
        joint left with an unknown coordinate is NOT_TRACKED; a row not interpolated is
        ``first``'s (rounded to float32). And (N, 25, 3) float64 world metres, the joints
        moved as :func:`~skelfuse.protocol.transform.apply` moves them (a row not
        interpolated: ``first``'s joints as they are).
    """
    dtype = np.float32 if first.dtype == second.dtype == np.float32 else np.float64
    joints = np.empty(first.shape, np.float32)
    states = np.empty(first_states.shape, np.uint8)
    world = np.empty(first.shape)
    _to_world_loop(
        plain(first, dtype),
        plain(second, dtype),
        plain(first_states, np.uint8),
        plain(second_states, np.uint8),
        plain(alpha),
        plain(interpolate, np.bool_),
        plain(pose_of_row, np.intp),
        plain(poses),
        _NOT_TRACKED,
        joints,
        states,
        world,
    )
    return joints, states, world


@jit
def _to_world_loop(
    first: Float32Array | FloatArray,
    second: Float32Array | FloatArray,
    first_states: StateArray,
    second_states: StateArray,
    alpha: FloatArray,
    interpolate: npt.NDArray[np.bool_],
    pose_of_row: npt.NDArray[np.intp],
    poses: FloatArray,
    not_tracked: int,
    joints: Float32Array,
    states: StateArray,
    world: FloatArray,
) -> None:
    """:func:`to_world` into ``joints``, ``states`` and ``world``: one loop, as it moves each
    joint as soon as it is interpolated."""
    value = np.empty(3)
    for n in range(first.shape[0]):
        fraction = alpha[n]
        rest = 1.0 - fraction
        later = fraction >= 0.5
        pose = poses[pose_of_row[n]]
        for j in range(first.shape[1]):
            if not interpolate[n]:
                for c in range(3):
                    joints[n, j, c] = first[n, j, c]
                    value[c] = np.float64(first[n, j, c])  # as it is, not rounded
                states[n, j] = first_states[n, j]
            else:  # sensors._lerp's rule, joint by joint
                both = True
                for c in range(3):
                    if not (np.isfinite(first[n, j, c]) and np.isfinite(second[n, j, c])):
                        both = False
                if both:
                    for c in range(3):
                        value[c] = rest * np.float64(first[n, j, c]) + fraction * np.float64(
                            second[n, j, c]
                        )
                    state = min(first_states[n, j], second_states[n, j])
                else:
                    for c in range(3):
                        value[c] = np.float64(second[n, j, c] if later else first[n, j, c])
                    state = second_states[n, j] if later else first_states[n, j]
                known = True
                for c in range(3):
                    joints[n, j, c] = np.float32(value[c])
                    if not np.isfinite(value[c]):
                        known = False
                    value[c] = np.float64(joints[n, j, c])  # moved as rounded to float32
                states[n, j] = state if known else not_tracked
            x, y, z = value[0], value[1], value[2]
            for i in range(3):  # protocol.transform.apply's sums
                world[n, j, i] = ((x * pose[i, 0] + y * pose[i, 1]) + z * pose[i, 2]) + pose[i, 3]
