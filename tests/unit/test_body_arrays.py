"""A sensor's bodies at an instant, all at once: the same bits as the body-by-body rule.

:func:`~skelfuse.fusion.sensors.body_arrays_at` interpolates every body of a frame in one set of
array operations and :func:`~skelfuse.fusion.pipeline.views_at` moves them to the world frame in
one product. The fused output is pinned byte for byte (test_golden_replay.py), so these tests
compare with the rule written body by body, as it was before the bodies were stacked.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion.pipeline import views_at
from skelfuse.fusion.sensors import SensorState, TimedFrame, bodies_at, body_arrays_at
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, look_at_pose
from skelfuse.protocol.wire import Body, Frame, decode, encode


def lerp_body(first: Body, second: Body, alpha: float) -> Body:
    """One body's interpolation, joint by joint (the rule before bodies were stacked)."""
    a = first.joints_m.astype(np.float64)
    b = second.joints_m.astype(np.float64)
    joints = (1.0 - alpha) * a + alpha * b
    both = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    nearer = b if alpha >= 0.5 else a
    joints[~both] = nearer[~both]
    states: npt.NDArray[np.uint8] = np.minimum(first.states, second.states)
    nearer_states = second.states if alpha >= 0.5 else first.states
    states[~both] = nearer_states[~both]
    states[~np.isfinite(joints).all(axis=1)] = TrackingState.NOT_TRACKED
    return Body(first.tracking_id, joints.astype(np.float32), states)


def reference(before: TimedFrame, after: TimedFrame, t_s: float) -> tuple[Body, ...]:
    """Interpolation between two frames close in time, body by body."""
    alpha = (t_s - before.t_server_s) / (after.t_server_s - before.t_server_s)
    earlier = {b.tracking_id: b for b in before.frame.bodies}
    later = {b.tracking_id: b for b in after.frame.bodies}
    if alpha < 0.5:
        return tuple(
            lerp_body(b, later[b.tracking_id], alpha) if b.tracking_id in later else b
            for b in before.frame.bodies
        )
    return tuple(
        lerp_body(earlier[b.tracking_id], b, alpha) if b.tracking_id in earlier else b
        for b in after.frame.bodies
    )


def random_frame(rng: np.random.Generator, t_s: float, ids: list[int]) -> TimedFrame:
    bodies = []
    for tracking_id in ids:
        joints = rng.normal(0.0, 1.5, (JOINT_COUNT, 3)).astype(np.float32)
        states = rng.integers(0, 3, JOINT_COUNT).astype(np.uint8)
        lost = rng.random(JOINT_COUNT) < 0.15
        joints[lost] = np.nan
        states[lost] = TrackingState.NOT_TRACKED
        bodies.append(Body(tracking_id, joints, states))
    return TimedFrame(t_s, Frame(1, int(t_s * 1e9), tuple(bodies)))


def same_bits(got: tuple[Body, ...], want: tuple[Body, ...]) -> None:
    assert [b.tracking_id for b in got] == [b.tracking_id for b in want]
    for g, w in zip(got, want, strict=True):
        assert g.joints_m.dtype == w.joints_m.dtype and g.states.dtype == w.states.dtype
        assert g.joints_m.tobytes() == w.joints_m.tobytes()
        assert g.states.tobytes() == w.states.tobytes()


@pytest.mark.parametrize("seed", range(40))
def test_all_bodies_at_once_give_the_bits_of_body_by_body(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # Bodies leave, arrive and change order between the frames; sometimes all are finite.
    first_ids = [int(i) for i in rng.permutation(8)[: rng.integers(1, 7)]]
    second_ids = [int(i) for i in rng.permutation(8)[: rng.integers(1, 7)]]
    if seed % 4 == 0:
        second_ids = list(first_ids)
    before = random_frame(rng, 10.0, first_ids)
    after = random_frame(rng, 10.0 + 1 / 30, second_ids)
    if seed % 5 == 0:
        for frame in (before, after):
            for body in frame.frame.bodies:
                body.joints_m[~np.isfinite(body.joints_m)] = 0.5
    for t_s in (10.0 + rng.uniform(0.0, 1 / 60), 10.0 + rng.uniform(1 / 60, 1 / 30)):
        got = bodies_at(deque([before, after]), t_s, max_gap_s=0.2, max_age_s=0.05)
        assert got is not None
        same_bits(got, reference(before, after, t_s))


def test_a_frame_stacks_its_bodies_once_and_the_result_is_not_written_to() -> None:
    rng = np.random.default_rng(3)
    before, after = random_frame(rng, 1.0, [1, 2]), random_frame(rng, 1.1, [2, 1])
    stacked = before.arrays()
    assert before.arrays() is stacked
    copy = stacked.joints_m.copy(), stacked.states.copy()
    body_arrays_at([before, after], 1.04, 0.2, 0.05)
    body_arrays_at([before, after], 1.06, 0.2, 0.05)
    assert stacked.joints_m.tobytes() == copy[0].tobytes()
    assert stacked.states.tobytes() == copy[1].tobytes()


def test_an_empty_frame_gives_no_bodies() -> None:
    empty = TimedFrame(1.0, Frame(1, 10**9, ()))
    arrays = body_arrays_at([empty], 1.01, 0.2, 0.05)
    assert arrays is not None and arrays.tracking_ids == []
    assert arrays.joints_m.shape == (0, JOINT_COUNT, 3)


def sensor(sensor_id: str, frames: list[TimedFrame]) -> SensorState:
    state = SensorState(sensor_id, "kinect_v2", "t", b"r", 30.0)
    state.frames = deque(frames)
    return state


def test_views_move_every_body_as_the_transform_moves_it_alone() -> None:
    rng = np.random.default_rng(5)
    poses: dict[str, Matrix4] = {
        "a": look_at_pose((2.5, 1.2, -1.0), (0.0, 0.9, 0.3)),
        "b": look_at_pose((-3.0, 0.8, 2.0), (0.1, 1.0, 0.0)),
    }
    sensors = [
        sensor("a", [random_frame(rng, 5.0, [4, 5, 6]), random_frame(rng, 5.033, [6, 5, 4])]),
        sensor("b", [random_frame(rng, 5.01, [1])]),
        sensor("c", [random_frame(rng, 5.0, [9])]),  # no pose: left out
    ]
    views = views_at(sensors, poses.get, 5.02, 0.2)
    assert [(v.sensor_id, v.tracking_id) for v in views] == [
        ("a", 6), ("a", 5), ("a", 4), ("b", 1)
    ]  # fmt: skip
    for view in views:
        state = sensors[0] if view.sensor_id == "a" else sensors[1]
        bodies = bodies_at(state.frames, 5.02, 0.2, 0.05) or ()
        (body,) = [b for b in bodies if b.tracking_id == view.tracking_id]
        want = apply(poses[view.sensor_id], body.joints_m)
        assert view.joints_world.dtype == np.float64
        assert view.joints_world.tobytes() == want.tobytes()
        assert view.states.tobytes() == body.states.tobytes()
        assert view.sensor_position is not None
        assert view.sensor_position.tobytes() == poses[view.sensor_id][:3, 3].tobytes()


def test_a_decoded_frames_arrays_are_the_decoders_without_a_copy() -> None:
    """A frame from the wire is stacked once, by the decoder: ``arrays()`` hands out those
    arrays (the bodies' own memory); a frame built here is stacked from its bodies. The values
    are the same either way."""
    built = random_frame(np.random.default_rng(5), 1.0, [3, 9, 4]).frame
    decoded = decode(encode(built))
    assert isinstance(decoded, Frame) and decoded.stacked is not None
    for frame in (built, decoded):
        arrays = TimedFrame(1.0, frame).arrays()
        assert arrays.tracking_ids == [3, 9, 4]
        np.testing.assert_array_equal(arrays.joints_m, np.array([b.joints_m for b in frame.bodies]))
        np.testing.assert_array_equal(arrays.states, np.array([b.states for b in frame.bodies]))
    decoded_arrays = TimedFrame(1.0, decoded).arrays()
    assert decoded_arrays.joints_m is decoded.stacked[0]
    assert decoded_arrays.states is decoded.stacked[1]
    built_arrays = TimedFrame(1.0, built).arrays()
    assert not np.shares_memory(built_arrays.joints_m, built.bodies[0].joints_m)
