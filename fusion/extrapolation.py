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
  their mirror labels differ; :mod:`skelfuse.fusion.measured_motion`). A measurement, not a
  model: it neither lags a change of pace as a filter's velocity does nor feeds the fused
  estimate back into itself. Joints no on-time view saw at both times are carried as ``track`` does.
- ``track``: the newest frame moved by the motion of the person that body was at the last
  step, as that person's filter estimates it per joint (:mod:`skelfuse.fusion.track_motion`):
  smoother than one sensor's own frame-to-frame difference, but it lags. A body with no such
  estimate (a new person) is held at its newest frame.
- ``own``: linear from the sensor's own two newest frames (:func:`extrapolated_bodies`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.identity import ViewKey
from skelfuse.fusion.measured_motion import carried_worlds, measured_from_arrays
from skelfuse.fusion.moving import world_position
from skelfuse.fusion.pipeline import FusionPipeline, PoseLookup
from skelfuse.fusion.sensors import SensorState, TimedFrame
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.track_motion import PersonMotion, track_members, track_motions
from skelfuse.fusion.views import View
from skelfuse.fusion.world_views import (
    Gathered,
    SensorBodies,
    gather_at,
    resolve_with_rows,
    views_of,
)
from skelfuse.protocol.transform import apply
from skelfuse.protocol.wire import Body

FloatArray = npt.NDArray[np.float64]
Rows = list[FloatArray] | FloatArray
"""Bodies' (25, 3) joints, one per body: a list, or the rows of one (B, 25, 3) array."""


@dataclass(frozen=True, slots=True)
class LatePredictor:
    """How :func:`views_with_late` carries late bodies (``alignment.predictor``): the persons'
    filtered motions (``track``, and ``views`` for the joints the on-time views miss), and for
    ``views`` which person each body was at the last step (None under ``track``)."""

    motions: Mapping[ViewKey, PersonMotion]
    members: Mapping[ViewKey, tuple[int, bool]] | None = None


class _MotionsOnDemand(Mapping[ViewKey, PersonMotion]):
    """:func:`~skelfuse.fusion.track_motion.track_motions` of ``pipeline``, read at the first
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
    :func:`~skelfuse.fusion.measured_motion.measured_from_arrays`' answer, None: nothing
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
