"""All sensors' bodies at an instant in one pass: the bits of the sensor-by-sensor rule.

:func:`~skelfuse.fusion.world_views.views_at` interpolates every sensor's bodies in one
element-wise pass and moves them to the world frame in one stacked product. The fused output is
pinned byte for byte (test_golden_replay.py), so these tests compare with the rule written
sensor by sensor (:func:`~skelfuse.fusion.sensors.body_arrays_at`, then
:func:`~skelfuse.protocol.transform.apply`), as it was before the sensors were stacked.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np
import pytest

from skelfuse.fusion.sensors import SensorState, TimedFrame, body_arrays_at
from skelfuse.fusion.views import View
from skelfuse.fusion.world_views import gather_at, resolve, views_at, views_of
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, look_at_pose
from skelfuse.protocol.wire import Body, Frame


def sensor_by_sensor(
    sensors: list[SensorState], pose_of: Callable[[str], Matrix4 | None], t_s: float, gap_s: float
) -> list[View]:
    """The rule one sensor at a time (the pipeline's views_at before the batch)."""
    views: list[View] = []
    for sensor in sensors:
        pose = pose_of(sensor.sensor_id)
        if not sensor.connected or pose is None:
            continue
        bodies = body_arrays_at(sensor.frames, t_s, gap_s, 1.5 / max(sensor.nominal_fps, 1.0))
        if bodies is None or not bodies.tracking_ids:
            continue
        world = apply(pose, bodies.joints_m)
        hands = bodies.hands or [None] * len(bodies.tracking_ids)
        views.extend(
            View(sensor.sensor_id, i, w, s, pose[:3, 3], sensor.sensor_type, h)
            for i, w, s, h in zip(bodies.tracking_ids, world, bodies.states, hands, strict=True)
        )
    return views


def frame(rng: np.random.Generator, t_s: float, ids: list[int], lost: float) -> TimedFrame:
    bodies = []
    for tracking_id in ids:
        joints = rng.normal(0.0, 1.5, (JOINT_COUNT, 3)).astype(np.float32)
        states = rng.integers(0, 3, JOINT_COUNT).astype(np.uint8)
        missing = rng.random(JOINT_COUNT) < lost
        joints[missing] = np.nan
        if rng.random() < 0.5:  # else a sensor's NaN with a state: fusion says NOT_TRACKED
            states[missing] = TrackingState.NOT_TRACKED
        bodies.append(Body(tracking_id, joints, states))
    return TimedFrame(t_s, Frame(1, int(t_s * 1e9), tuple(bodies)))


def random_sensor(rng: np.random.Generator, name: str, t_s: float) -> SensorState:
    """A sensor whose two newest frames straddle ``t_s`` in one of the ways the rule tells
    apart: same bodies (usual), bodies changed, a missing joint, a long gap, only older."""
    ids = [int(i) for i in rng.permutation(9)[: rng.integers(1, 7)]]
    kind = rng.integers(0, 6)
    phase = rng.uniform(0.0, 1 / 30)
    first_t, second_t = t_s - phase, t_s - phase + 1 / 30
    later_ids = list(ids)
    lost = 0.0
    if kind == 1:
        later_ids = [int(i) for i in rng.permutation(9)[: rng.integers(1, 7)]]
    elif kind == 2:
        lost = 0.1
    elif kind == 3:
        second_t = t_s - phase + 0.5  # too far apart to interpolate
    elif kind == 4:
        first_t, second_t = t_s - 1 / 30 - phase / 4, t_s - phase / 4  # newest is older
    elif kind == 5:
        later_ids = ids[::-1]
    state = SensorState(name, "kinect_v2", "t", b"r", 30.0)
    state.frames = deque(
        [
            frame(rng, first_t - 1 / 30, ids, lost),
            frame(rng, first_t, ids, lost),
            frame(rng, second_t, later_ids, lost),
        ]
    )
    return state


def same_views(got: list[View], want: list[View]) -> None:
    assert [(v.sensor_id, v.tracking_id) for v in got] == [
        (v.sensor_id, v.tracking_id) for v in want
    ]
    for g, w in zip(got, want, strict=True):
        assert g.joints_world.dtype == w.joints_world.dtype == np.float64
        assert g.joints_world.tobytes() == w.joints_world.tobytes()
        assert g.states.tobytes() == w.states.tobytes()
        assert g.sensor_position is not None and w.sensor_position is not None
        assert g.sensor_position.tobytes() == w.sensor_position.tobytes()
        assert (g.sensor_type, g.hands) == (w.sensor_type, w.hands)


@pytest.mark.parametrize("seed", range(60))
def test_all_sensors_at_once_give_the_bits_of_sensor_by_sensor(seed: int) -> None:
    rng = np.random.default_rng(seed)
    t_s = 1000.0 + rng.uniform(0.0, 1.0)
    names = [f"s{k}" for k in range(int(rng.integers(1, 12)))]
    sensors = [random_sensor(rng, name, t_s) for name in names]
    poses: dict[str, Matrix4] = {
        name: look_at_pose(
            (float(rng.uniform(-4, 4)), float(rng.uniform(0.5, 2)), float(rng.uniform(-4, 4))),
            (0.0, 0.9, 0.0),
        )
        for name in names
        if rng.random() < 0.9  # some uncalibrated
    }
    if seed % 7 == 0 and sensors:
        sensors[0].connected = False
    same_views(
        views_at(sensors, poses.get, t_s, 0.2), sensor_by_sensor(sensors, poses.get, t_s, 0.2)
    )


@pytest.mark.parametrize("seed", range(20))
def test_several_instants_resolved_together_give_the_bits_of_each_alone(seed: int) -> None:
    """The late path resolves the on-time sensors at two instants and the late sensors' newest
    frames in one pass and one product (fusion/extrapolation.py): every group's views must be
    what that group alone gives, and what the rule gives sensor by sensor."""
    rng = np.random.default_rng(100 + seed)
    t_s = 1000.0 + rng.uniform(0.0, 1.0)
    names = [f"s{k}" for k in range(int(rng.integers(1, 12)))]
    sensors = [random_sensor(rng, name, t_s) for name in names]
    poses = {
        name: look_at_pose((3.0, 1.5, float(k)), (0.0, 0.9, 0.0)) for k, name in enumerate(names)
    }
    split = int(rng.integers(0, len(sensors) + 1))
    instants = [
        (sensors[:split], t_s),
        (sensors[:split], t_s - 0.02),
        (sensors[split:], t_s + 0.01),
    ]
    together = resolve([gather_at(group, poses.get, t, 0.2) for group, t in instants])
    assert len(together) == 3
    for (group, t), resolved in zip(instants, together, strict=True):
        (alone,) = resolve([gather_at(group, poses.get, t, 0.2)])
        same_views(views_of(resolved, t), views_of(alone, t))
        same_views(views_of(resolved, t), sensor_by_sensor(group, poses.get, t, 0.2))
    assert resolve([[], []]) == [[], []]


def test_no_sensor_gives_no_views_and_cached_frames_are_not_written_to() -> None:
    rng = np.random.default_rng(2)
    assert views_at([], lambda _: None, 1.0, 0.2) == []
    sensor = random_sensor(rng, "a", 5.0)
    copies = [(f.arrays().joints_m.copy(), f.arrays().states.copy()) for f in sensor.frames]
    pose = look_at_pose((2.0, 1.0, 2.0), (0.0, 0.9, 0.0))
    for view in views_at([sensor], lambda _: pose, 5.0, 0.2):
        view.joints_world[:] = 0.0  # the views' own arrays
    for f, (joints, states) in zip(sensor.frames, copies, strict=True):
        assert f.arrays().joints_m.tobytes() == joints.tobytes()
        assert f.arrays().states.tobytes() == states.tobytes()
