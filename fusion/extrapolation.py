"""Late sensors under the ``deadline`` alignment: their bodies carried a short way past their
newest frame to the instant being fused (docs/fusion.md §2–3).

The ``deadline`` policy (:mod:`skelfuse.fusion.alignment`) bounds how far (``alignment_max_
extrapolation_s``, about one frame period); this module only does the arithmetic and builds the
instant's views: on-time sensors interpolated as always (:func:`~skelfuse.fusion.pipeline.
views_at`), late ones carried forward, those beyond the bound left out. Three predictors
(``alignment.predictor``):

- ``views`` (the default): the newest frame moved by what the *on-time* views of the same person
  saw happen between that frame's capture and the instant: each on-time view interpolated at
  both times, the difference averaged over those views per joint (left and right swapped where
  their mirror labels differ; :func:`measured_displacements`). A measurement, not a
  model: it neither lags a change of pace as a filter's velocity does nor feeds the fused
  estimate back into itself. Joints no on-time view saw at both times are carried as ``track`` does.
- ``track``: the newest frame moved by the motion of the person that body was at the last
  step, as that person's filter estimates it per joint (:func:`track_motions`):
  smoother than one sensor's own frame-to-frame difference, but it lags. A body with no such
  estimate (a new person) is held at its newest frame.
- ``own``: linear from the sensor's own two newest frames (:func:`extrapolated_bodies`).

Track motion (first section): a late sensor's own two newest frames give a noisy velocity (the
difference of two noisy samples, divided by 33 ms); the person's temporal filter
(:mod:`skelfuse.fusion.filters`) has already estimated each joint's velocity, and acceleration,
from every sensor over many instants. :func:`track_motions` reads that estimate from the
pipeline's per-person state, keyed by the (sensor, tracking id) bodies that were the person at
the last step, so that a late body can be moved by its own person's motion; nothing here changes
the pipeline's state.

The ``views`` predictor's measurement (last section): each on-time view is interpolated at both
times (the late frame's capture and the instant); the difference is averaged over a person's
views joint by joint, over the views that have the joint Tracked at both times (an Inferred
joint is the sensor's guess, not a measurement), with left and right swapped for a view whose
mirror label differs from the late body's. One compiled loop does it per late body: per joint
coordinate, the differences where both times are Tracked, added view after view to 0.0 in the
person's view order, divided by their count; each late body's row straight from its person's
views, found by id. :func:`carried_worlds` then carries the late bodies by their scaled
measurement.

Shapes: (25, 3) joints per body, world frame, metres; times in seconds.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.filters import JointFilter, KalmanState, OneEuroFilter
from skelfuse.fusion.identity import ViewKey
from skelfuse.fusion.pipeline import FusionPipeline, PoseLookup
from skelfuse.fusion.sensors import SensorState, TimedFrame, world_position
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.views import View
from skelfuse.fusion.world_views import (
    Gathered,
    SensorBodies,
    StackedRows,
    gather_at,
    resolve_with_rows,
    views_of,
)
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, TrackingState
from skelfuse.protocol.transform import apply
from skelfuse.protocol.wire import Body

FloatArray = npt.NDArray[np.float64]
Rows = list[FloatArray] | FloatArray
"""Bodies' (25, 3) joints, one per body: a list, or the rows of one (B, 25, 3) array."""

# --- Track motion: how each tracked person is moving, per joint, from their filter ---------------


_MIRROR = np.array(MIRROR_PERMUTATION, dtype=np.intp)


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


# --- Late bodies carried to the instant ----------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LatePredictor:
    """How :func:`views_with_late` carries late bodies (``alignment.predictor``): the persons'
    filtered motions (``track``, and ``views`` for the joints the on-time views miss), and for
    ``views`` which person each body was at the last step (None under ``track``)."""

    motions: Mapping[ViewKey, PersonMotion]
    members: Mapping[ViewKey, tuple[int, bool]] | None = None


class _MotionsOnDemand(Mapping[ViewKey, PersonMotion]):
    """:func:`track_motions` of ``pipeline``, read at the first
    look: under ``views`` an instant whose late bodies the on-time views measured whole never
    looks (the pipeline is not updated before :func:`views_with_late` has run)."""

    def __init__(self, pipeline: FusionPipeline, accelerate: bool) -> None:
        self._pipeline = pipeline
        self._accelerate = accelerate
        self._motions: dict[ViewKey, PersonMotion] | None = None

    def _all(self) -> dict[ViewKey, PersonMotion]:
        if self._motions is None:
            self._motions = track_motions(self._pipeline, self._accelerate)
        return self._motions

    def __getitem__(self, key: ViewKey) -> PersonMotion:
        return self._all()[key]

    def __iter__(self) -> Iterator[ViewKey]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


def extrapolated_bodies(
    frames: deque[TimedFrame] | list[TimedFrame], t_s: float, max_gap_s: float
) -> tuple[Body, ...]:
    """The sensor's bodies at ``t_s`` (after its newest frame), extrapolated linearly from its
    two newest frames.

    A body in both frames (same tracking id) moves on at the velocity between them, joint by
    joint, with the lower tracking state of the two; a joint missing from either frame, a body
    only in the newest frame, or frames more than ``max_gap_s`` apart keep the newest frame's
    values (held, not extrapolated). Joints (J, 3) float32 metres, sensor frame.

    Raises:
        ValueError: no frames, or ``t_s`` is before the newest frame.
    """
    if not frames:
        raise ValueError("no frames to extrapolate from")
    newest = frames[-1]
    if t_s < newest.t_server_s:
        raise ValueError(f"t_s {t_s} is before the newest frame ({newest.t_server_s})")
    if len(frames) < 2:
        return newest.frame.bodies
    before = frames[-2]
    gap = newest.t_server_s - before.t_server_s
    if not 0.0 < gap <= max_gap_s:
        return newest.frame.bodies
    ahead = (t_s - newest.t_server_s) / gap
    earlier = {body.tracking_id: body for body in before.frame.bodies}
    return tuple(
        _extrapolate_body(earlier[body.tracking_id], body, ahead)
        if body.tracking_id in earlier
        else body
        for body in newest.frame.bodies
    )


def _extrapolate_body(first: Body, second: Body, ahead: float) -> Body:
    """``second`` moved on by ``ahead`` × (second − first); ``ahead`` ≥ 0 in frame gaps."""
    a = first.joints_m.astype(np.float64)
    b = second.joints_m.astype(np.float64)
    joints = b + ahead * (b - a)
    both = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    joints[~both] = b[~both]
    states: npt.NDArray[np.uint8] = np.minimum(first.states, second.states)
    states[~both] = second.states[~both]
    return Body(second.tracking_id, joints.astype(np.float32), states)


def carried_by_motion(
    joints_world: npt.NDArray[np.float64], motion: PersonMotion | None, from_s: float, to_s: float
) -> npt.NDArray[np.float64]:
    """A late body's world joints (25, 3) at ``from_s`` moved to ``to_s`` (seconds) by its
    person's filtered motion; joints without an estimate (or no motion at all) are held.

    Raises:
        ValueError: ``to_s`` is before ``from_s``.
    """
    if to_s < from_s:
        raise ValueError(f"to_s {to_s} is before from_s {from_s}")
    if motion is None:
        return joints_world.copy()
    moved = motion.displacement(from_s, to_s)
    carried: npt.NDArray[np.float64] = joints_world + np.where(np.isfinite(moved), moved, 0.0)
    return carried


def late_motions(pipeline: FusionPipeline, settings: FusionSettings) -> LatePredictor | None:
    """What :func:`views_with_late` carries late bodies with under ``settings``: each body's
    person motion (``track``), that and each body's person (``views``), or None (``own``)."""
    if settings.alignment.predictor == "own":
        return None
    motions = _MotionsOnDemand(pipeline, settings.alignment.predict_acceleration)
    if settings.alignment.predictor == "track":
        return LatePredictor(motions)
    return LatePredictor(motions, track_members(pipeline))


def views_with_late(
    sensors: Iterable[SensorState],
    pose_of: PoseLookup,
    t_s: float,
    gap_s: float,
    late: Mapping[str, float],
    left_out: Collection[str],
    predictor: LatePredictor | None = None,
) -> list[View]:
    """Steps 1–2 of the pipeline for an instant fused at its deadline: every connected,
    calibrated sensor's bodies at ``t_s`` in the world frame, in sensor order.

    Under ``views`` a sensor late by ``h`` is carried ``h / H`` of what the on-time views of
    each body's person saw happen in the ``H`` before the instant, ``H`` the furthest-late
    sensor's horizon: exactly its own measurement for that sensor, the same line for the others
    (one more interpolation of the on-time sensors per instant instead of one per late sensor).
    The on-time sensors at both times and the late sensors' newest frames go to the world in one
    product (:func:`~skelfuse.fusion.world_views.resolve`: the same bits as one by one).

    Args:
        sensors: the sensors' frame buffers (times on the server clock).
        pose_of: each sensor's pose; sensors without one are left out.
        t_s: the instant, server clock, seconds.
        gap_s: frames further apart than this are not interpolated (or extrapolated) between.
        late: the sensors to extrapolate (their newest frame is before ``t_s``; the policy
            checked the bound).
        left_out: the sensors too far behind to use at this instant.
        predictor: what :func:`late_motions` gives: the ``views`` or ``track`` predictor;
            None: the ``own`` predictor.
    """
    sensors = list(sensors)
    on_time = [s for s in sensors if s.sensor_id not in late and s.sensor_id not in left_out]
    members = None if predictor is None or not late else predictor.members  # ``views`` only
    reach = max(late.values()) if members is not None else 0.0
    groups = [gather_at(on_time, pose_of, t_s, gap_s)]
    if members is not None:
        groups.append(gather_at(on_time, pose_of, t_s - reach, gap_s))
    if predictor is not None:
        groups.append(_newest_of([s for s in sensors if s.sensor_id in late], pose_of))
    resolved, stacked = resolve_with_rows(groups)
    now: dict[str, list[View]] = {}
    for view in views_of(resolved[0], t_s):
        now.setdefault(view.sensor_id, []).append(view)
    carried: dict[str, Rows] = {}
    if predictor is not None:
        # The rows of each group in the stacked arrays (groups in order: now, then, newest).
        rows = sum(len(b.bodies.tracking_ids) for b in resolved[0])
        if members is not None:
            rows += sum(len(b.bodies.tracking_ids) for b in resolved[1])
        measured = None
        if members is not None:
            measured = measured_from_arrays(
                resolved[-1], members, resolved[0], resolved[1],
                None if stacked is None else (stacked[0][:rows], stacked[1][:rows]),
            )  # fmt: skip
        newest_worlds = None if stacked is None else stacked[0][rows:]
        carried = _carried_late(
            resolved[-1], late, (reach, measured), predictor, t_s, newest_worlds
        )
    return _in_sensor_order(sensors, now, carried, (late, left_out), pose_of, predictor, t_s, gap_s)


def _in_sensor_order(
    sensors: list[SensorState],
    now: dict[str, list[View]],
    carried: dict[str, Rows],
    late_and_left_out: tuple[Mapping[str, float], Collection[str]],
    pose_of: PoseLookup,
    predictor: LatePredictor | None,
    t_s: float,
    gap_s: float,
) -> list[View]:
    """Every sensor's views at ``t_s`` in sensor order: the on-time ones as interpolated
    (``now``), the late ones as carried (``carried``; by their own frames without a
    predictor), none of those left out."""
    late, left_out = late_and_left_out
    views: list[View] = []
    for sensor in sensors:
        if sensor.sensor_id in left_out:
            continue
        if sensor.sensor_id not in late:
            views += now.get(sensor.sensor_id, [])
            continue
        pose = pose_of(sensor.sensor_id)
        if not sensor.connected or pose is None or not sensor.frames:
            continue
        bodies = sensor.frames[-1].frame.bodies
        if predictor is None:
            bodies = extrapolated_bodies(sensor.frames, t_s, gap_s)
            worlds: Rows = [apply(pose, body.joints_m) for body in bodies]
        else:
            worlds = carried.get(sensor.sensor_id, [])
        position = world_position(sensor.frames, t_s, pose) if sensor.moving else pose[:3, 3]
        sensor_id, sensor_type = sensor.sensor_id, sensor.sensor_type
        views.extend(
            View(sensor_id, body.tracking_id, world, body.states, position, sensor_type)
            for body, world in zip(bodies, worlds, strict=True)
        )
    return views


def _newest_of(late_sensors: list[SensorState], pose_of: PoseLookup) -> Gathered:
    """The late sensors that are connected and calibrated and have a body, each with its pose
    and its newest frame's bodies."""
    newest: Gathered = []
    for sensor in late_sensors:
        pose = pose_of(sensor.sensor_id)
        if (
            sensor.connected
            and pose is not None
            and sensor.frames
            and sensor.frames[-1].frame.bodies
        ):
            newest.append((sensor, pose, sensor.frames[-1].arrays()))
    return newest


def _carried_late(
    newest: list[SensorBodies],
    late: Mapping[str, float],
    moved: tuple[float, FloatArray | None],
    predictor: LatePredictor,
    t_s: float,
    newest_worlds: FloatArray | None = None,
) -> dict[str, Rows]:
    """Every late sensor's newest bodies in the world (``newest``), carried to ``t_s``
    (seconds): a sensor late by ``h`` by ``h / H`` × what the on-time views measured of each
    body's person in the ``H`` before the instant (``moved``: ``H`` and
    :func:`measured_from_arrays`' answer, None: nothing
    measured), joint by joint where they saw it; the other joints by the person's filtered
    motion (:func:`carried_by_motion`). (25, 3) world metres per body, per sensor id.

    All sensors at once (one sum), the same bits as body by body. ``newest_worlds``: the
    bodies' world joints stacked in ``newest``'s order (B, 25, 3), or None to stack them here."""
    if not newest:
        return {}
    counts = [len(b.bodies.tracking_ids) for b in newest]
    if newest_worlds is None:
        newest_worlds = np.concatenate([b.world for b in newest])
    reach, measured = moved
    scales = [late[b.sensor.sensor_id] / reach if reach > 0.0 else 0.0 for b in newest]
    # Each body's measurement times its sensor's scale (B, 25, 3): the same products as one
    # body at a time.
    if measured is None:
        measured = np.full(newest_worlds.shape, np.nan)
    row_scales = np.array(scales).repeat(counts)  # the method: np.repeat's wrapper costs more
    worlds_seen, seen, whole = carried_worlds(newest_worlds, row_scales, measured)
    if all(whole.tolist()):  # every joint of every body measured (the usual instant): as they are
        return _by_sensor(newest, counts, worlds_seen)
    worlds: list[FloatArray] = list(worlds_seen)
    # Bodies with a joint the on-time views did not see: those joints by the filter's motion.
    unseen = np.flatnonzero(~whole).tolist()
    if unseen:
        newest_s = np.repeat([b.sensor.frames[-1].t_server_s for b in newest], counts).tolist()
        keys = [(b.sensor.sensor_id, body) for b in newest for body in b.bodies.tracking_ids]
        for row in unseen:
            world = carried_by_motion(
                newest_worlds[row], predictor.motions.get(keys[row]), newest_s[row], t_s
            )
            world[seen[row]] = worlds_seen[row][seen[row]]
            worlds[row] = world
    return _by_sensor(newest, counts, worlds)


def _by_sensor(newest: list[SensorBodies], counts: list[int], rows: Rows) -> dict[str, Rows]:
    """``rows`` (one per body, sensor after sensor) split by sensor id, ``counts`` each."""
    split: dict[str, Rows] = {}
    lo = 0
    for b, count in zip(newest, counts, strict=True):
        split[b.sensor.sensor_id] = rows[lo : lo + count]
        lo += count
    return split


# --- The views predictor's measurement: how far the on-time views saw a person move --------------


IndexArray = npt.NDArray[np.intp]
_TRACKED = int(TrackingState.TRACKED)
"""Compared as a plain int: numpy compares a uint8 array with an IntEnum member 5× slower."""


def measured_displacements(
    late_keys: Iterable[ViewKey],
    members: Mapping[ViewKey, tuple[int, bool]],
    then: Mapping[ViewKey, View],
    now: Mapping[ViewKey, View],
) -> dict[ViewKey, FloatArray]:
    """How far each late body's person moved between the late frame's capture and the instant,
    as the on-time views of that person saw it, per joint: the mean over those views of (view
    at the instant − view at the capture), in the late body's joint order (left and right
    swapped for a view whose mirror label differs from the late body's), over the views where
    the joint is Tracked at both times.

    Args:
        late_keys: the late sensor's bodies (sensor id, tracking id).
        members: each body's (person id, mirror label) at the last step
            (:func:`track_members`).
        then: the on-time views interpolated at the late frame's capture time.
        now: the same views at the instant.

    Returns:
        (25, 3) metres per late body that has a person with an on-time view at both times, NaN
        where none of those views has the joint Tracked at both times; other bodies are absent.
    """
    keys = [k for k in now if k in then and k in members]
    if not keys:
        return {}
    joints = np.array([now[k].joints_world for k in keys] + [then[k].joints_world for k in keys])
    states = np.array([now[k].states for k in keys] + [then[k].states for k in keys])
    late_keys = list(late_keys)
    moved = _displacements(late_keys, members, keys, joints, states)
    present = {members[key][0] for key in keys}
    return {
        key: moved[row]
        for row, key in enumerate(late_keys)
        if members.get(key, (-1, False))[0] in present
    }


def _displacements(
    late_keys: list[ViewKey],
    members: Mapping[ViewKey, tuple[int, bool]],
    keys: list[ViewKey],
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
) -> FloatArray:
    """:func:`measured_displacements` of the on-time bodies ``keys`` (each with a person), their
    world joints and states at the instant (rows ``0..K-1``, (2K, 25, 3) and (2K, 25)) and at
    the late frame's capture (rows ``K..2K-1``): (L, 25, 3) metres, row by row ``late_keys``,
    all NaN for a body without a measurement."""
    unknown = (-1, False)  # a late body of nobody (person ids start at 1)
    late = [members.get(key, unknown) for key in late_keys]
    out = np.empty((len(late), JOINT_COUNT, 3))
    _displacements_loop(
        plain(joints),
        plain(states, np.uint8),
        np.array([members[key] for key in keys], dtype=np.intp).reshape(-1, 2),
        np.array(late, dtype=np.intp).reshape(-1, 2),
        _MIRROR,
        _TRACKED,
        out,
    )
    return out


def measured_from_arrays(
    newest: list[SensorBodies],
    members: Mapping[ViewKey, tuple[int, bool]],
    now: list[SensorBodies],
    then: list[SensorBodies],
    stacked: StackedRows | None = None,
) -> FloatArray:
    """:func:`measured_displacements` of the late bodies ``newest`` from the on-time sensors'
    bodies at the instant (``now``) and at the furthest-late sensor's capture (``then``), on
    their arrays: rows gathered by key instead of views looked up one by one (the same values).
    (B, 25, 3) metres in ``newest``'s body order, all NaN for a body without a measurement.

    ``stacked``: ``now``'s then ``then``'s world joints and states in one array each, row after
    row (what :func:`~skelfuse.fusion.world_views.resolve_with_rows` computed them in), or None
    to stack them here."""
    late_keys = [(b.sensor.sensor_id, i) for b in newest for i in b.bodies.tracking_ids]
    now_keys = [(b.sensor.sensor_id, i) for b in now for i in b.bodies.tracking_ids]
    if (
        now_keys
        # The same sensors with the same bodies at both times (compared sensor by sensor:
        # the same keys in the same order)
        and [(b.sensor.sensor_id, b.bodies.tracking_ids) for b in now]
        == [(b.sensor.sensor_id, b.bodies.tracking_ids) for b in then]
        and len(set(now_keys)) == len(now_keys)
        and all(key in members for key in now_keys)
    ):  # the usual instant: the same bodies at both times, each of a person: rows as they are
        if stacked is None:
            stacked = (
                np.concatenate([b.world for b in now] + [b.world for b in then]),
                np.concatenate([b.bodies.states for b in now] + [b.bodies.states for b in then]),
            )
        return _displacements(late_keys, members, now_keys, *stacked)
    then_keys = [(b.sensor.sensor_id, i) for b in then for i in b.bodies.tracking_ids]
    then_row = {key: row for row, key in enumerate(then_keys)}
    now_row = {key: row for row, key in enumerate(now_keys)}  # a key twice: the last row
    keys = [k for k in now_row if k in then_row and k in members]
    if not keys:
        return np.full((len(late_keys), JOINT_COUNT, 3), np.nan)
    rows = [now_row[k] for k in keys]
    rows += [len(now_keys) + then_row[k] for k in keys]
    joints = np.concatenate([b.world for b in now] + [b.world for b in then])[rows]
    states = np.concatenate([b.bodies.states for b in now] + [b.bodies.states for b in then])
    return _displacements(late_keys, members, keys, joints, states[rows])


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now, off any latency-bound path."""
    joints = np.zeros((2, JOINT_COUNT, 3))
    states = np.full((2, JOINT_COUNT), _TRACKED, dtype=np.uint8)
    moved = _displacements([("s", 0)], {("s", 0): (1, True)}, [("s", 0)], joints, states)
    carried_worlds(joints[:1], np.ones(1), moved)


@jit
def _displacements_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    members: IndexArray,
    late: IndexArray,
    mirror: IndexArray,
    tracked: int,
    out: FloatArray,
) -> None:
    """:func:`_displacements` into ``out`` (L, 25, 3): ``members`` (K, 2) each on-time body's
    person id and mirror label (1: its left and right are swapped into the person's order of a
    body labelled 0); ``late`` (L, 2) each late body's person id, or −1 for nobody (its row is
    all NaN, as is the row of a person no on-time body is of), and its label (1: its row is
    swapped back); ``mirror``: the left-right permutation; ``tracked``: the state measured."""
    count = members.shape[0]
    own = np.empty(count, dtype=np.intp)  # the row's person's on-time bodies, in their order
    for row in range(late.shape[0]):
        person = late[row, 0]
        views = 0
        for k in range(count):
            if person >= 0 and members[k, 0] == person:
                own[views] = k
                views += 1
        for j in range(out.shape[1]):
            # The late body's joint j is the person's joint ``wanted`` in the order of a body
            # labelled 0; each view's own joint for it is swapped if the view is labelled 1.
            wanted = mirror[j] if late[row, 1] != 0 else j
            for c in range(3):
                total = 0.0
                seen = 0
                for v in range(views):
                    k = own[v]
                    source = mirror[wanted] if members[k, 1] != 0 else wanted
                    if states[k, source] != tracked or states[count + k, source] != tracked:
                        continue  # Inferred at either time: the sensor's guess, not measured
                    moved = joints[k, source, c] - joints[count + k, source, c]
                    if np.isfinite(moved):
                        total += moved
                        seen += 1
                out[row, j, c] = total / max(seen, 1) if seen > 0 else np.nan


def carried_worlds(
    worlds: FloatArray, scales: FloatArray, measured: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """Late bodies carried by their scaled measurement where it is known.

    Args:
        worlds: (B, 25, 3) the late bodies' newest joints, world metres.
        scales: (B,) each body's share of the measurement (its sensor's horizon over the
            furthest-late one's).
        measured: (B, 25, 3) metres, :func:`measured_from_arrays`' answer (NaN: not measured).

    Returns:
        The carried joints (B, 25, 3), ``worlds + scale × measured`` where that product is
        finite and ``worlds + 0.0`` elsewhere; where it is finite, (B, 25, 3); and whether it
        is finite at every joint of a body, (B,).
    """
    out = np.empty(worlds.shape)
    seen = np.empty(worlds.shape, dtype=np.bool_)
    whole = np.empty(worlds.shape[0], dtype=np.bool_)
    _carried_loop(plain(worlds), plain(scales), plain(measured), out, seen, whole)
    return out, seen, whole


@jit
def _carried_loop(
    worlds: FloatArray,
    scales: FloatArray,
    measured: FloatArray,
    out: FloatArray,
    seen: npt.NDArray[np.bool_],
    whole: npt.NDArray[np.bool_],
) -> None:
    """:func:`carried_worlds` into ``out``, ``seen`` and ``whole``."""
    for b in range(worlds.shape[0]):
        every = True
        for j in range(worlds.shape[1]):
            for c in range(3):
                carried = scales[b] * measured[b, j, c]
                finite = np.isfinite(carried)
                # + 0.0 where unknown, as numpy's where-then-add does (-0.0 becomes +0.0).
                out[b, j, c] = worlds[b, j, c] + (carried if finite else 0.0)
                seen[b, j, c] = finite
                every = every and finite
        whole[b] = every
