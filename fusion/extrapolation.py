"""Late sensors under the ``deadline`` alignment: their bodies carried a short way past their
newest frame to the instant being fused (docs/fusion.md §2–3).

The ``deadline`` policy (:mod:`skelfuse.fusion.alignment`) bounds how far (``alignment_max_
extrapolation_s``, about one frame period); this module only does the arithmetic and builds the
instant's views: on-time sensors interpolated as always (:func:`~skelfuse.fusion.pipeline.
views_at`), late ones carried forward, those beyond the bound left out. Two predictors
(``alignment_predictor``):

- ``track`` (the default): the newest frame moved by the motion of the person that body was at
  the last step, as that person's filter estimates it per joint (:mod:`skelfuse.fusion.
  track_motion`): smoother than one sensor's own frame-to-frame difference. A body with no such
  estimate (a new person) is held at its newest frame.
- ``own``: linear from the sensor's own two newest frames (:func:`extrapolated_bodies`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Collection, Iterable, Mapping

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.identity import ViewKey
from skelfuse.fusion.pipeline import FusionPipeline, PoseLookup, views_at
from skelfuse.fusion.sensors import SensorState, TimedFrame
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.track_motion import PersonMotion, track_motions
from skelfuse.fusion.views import View
from skelfuse.protocol.transform import apply
from skelfuse.protocol.wire import Body


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


def late_motions(
    pipeline: FusionPipeline, settings: FusionSettings
) -> dict[ViewKey, PersonMotion] | None:
    """What :func:`views_with_late` carries late bodies with under ``settings``: each body's
    person motion (``alignment_predictor = "track"``), or None (``own``)."""
    if settings.alignment_predictor != "track":
        return None
    return track_motions(pipeline, settings.alignment_predict_acceleration)


def views_with_late(
    sensors: Iterable[SensorState],
    pose_of: PoseLookup,
    t_s: float,
    gap_s: float,
    late: Mapping[str, float],
    left_out: Collection[str],
    motions: Mapping[ViewKey, PersonMotion] | None = None,
) -> list[View]:
    """Steps 1–2 of the pipeline for an instant fused at its deadline: every connected,
    calibrated sensor's bodies at ``t_s`` in the world frame, in sensor order.

    Args:
        sensors: the sensors' frame buffers (times on the server clock).
        pose_of: each sensor's pose; sensors without one are left out.
        t_s: the instant, server clock, seconds.
        gap_s: frames further apart than this are not interpolated (or extrapolated) between.
        late: the sensors to extrapolate (their newest frame is before ``t_s``; the policy
            checked the bound).
        left_out: the sensors too far behind to use at this instant.
        motions: the ``track`` predictor: each body's person motion
            (:func:`~skelfuse.fusion.track_motion.track_motions`); None: the ``own`` predictor.
    """
    views: list[View] = []
    for sensor in sensors:
        if sensor.sensor_id in left_out:
            continue
        if sensor.sensor_id not in late:
            views += views_at((sensor,), pose_of, t_s, gap_s)
            continue
        pose = pose_of(sensor.sensor_id)
        if not sensor.connected or pose is None or not sensor.frames:
            continue
        if motions is None:
            bodies = extrapolated_bodies(sensor.frames, t_s, gap_s)
            worlds = [apply(pose, body.joints_m) for body in bodies]
        else:
            newest = sensor.frames[-1]
            bodies = newest.frame.bodies
            worlds = [
                carried_by_motion(
                    apply(pose, body.joints_m),
                    motions.get((sensor.sensor_id, body.tracking_id)),
                    newest.t_server_s,
                    t_s,
                )
                for body in bodies
            ]
        for body, world in zip(bodies, worlds, strict=True):
            views.append(
                View(
                    sensor.sensor_id,
                    body.tracking_id,
                    world,
                    body.states,
                    pose[:3, 3],
                    sensor.sensor_type,
                )
            )
    return views
