"""The late-sensor treatment under the ``deadline`` alignment (issue 11's raw latency target):
late views carried by their person's filtered motion (fusion/extrapolation.py), and the grid
put where late sensors are carried least, not waiting for sensors expected late anyway
(fusion/alignment.py), all driven by clocks of the test's own."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from skelfuse.fusion.alignment import Alignment, SensorTiming, replayed_horizons
from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.extrapolation import (
    LatePredictor,
    PersonMotion,
    carried_by_motion,
    measured_displacements,
    measured_from_arrays,
    track_motions,
    views_with_late,
)
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.fusion.sensors import BodyArrays, SensorState, TimedFrame
from skelfuse.fusion.settings import AlignmentSettings, BoneSettings, SmoothingSettings
from skelfuse.fusion.views import View
from skelfuse.fusion.world_views import SensorBodies
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import FusionSettings, Settings

P = 1 / 30
T0 = 1_800_000_000.0
DELIVERY_S = 0.002
"""Every frame reaches the server this long after capture: its one-way clock mapping reads each
capture this much late, so a view at server time t shows the walker at t − 2 ms."""
POSES = {
    "a": look_at_pose((0.0, 1.0, 3.0), (0.0, 0.9, 0.0)),
    "b": look_at_pose((3.0, 1.0, 0.0), (0.0, 0.9, 0.0)),
}


# --- the predictor on its own -------------------------------------------------------------------


def test_carried_by_motion_is_exact_for_constant_acceleration() -> None:
    """x(t) = x0 + v·t + a·t²/2 per joint: carried from 1.00 s to 1.02 s by the estimate held
    at 0.98 s (velocity at 0.98 s), the body lands on the curve exactly."""
    rng = np.random.default_rng(0)
    x0, v, a = (rng.normal(size=(JOINT_COUNT, 3)) for _ in range(3))

    def x(t: float) -> np.ndarray:
        return np.asarray(x0 + v * t + a * t * t / 2)

    motion = PersonMotion(v + a * 0.98, a, np.full((JOINT_COUNT, 3), 0.98))
    np.testing.assert_allclose(carried_by_motion(x(1.0), motion, 1.0, 1.02), x(1.02), atol=1e-12)
    still = motion.without_acceleration()
    np.testing.assert_allclose(
        carried_by_motion(x(1.0), still, 1.0, 1.02), x(1.0) + (v + a * 0.98) * 0.02, atol=1e-12
    )


def test_joints_without_an_estimate_and_bodies_without_a_person_are_held() -> None:
    joints = np.ones((JOINT_COUNT, 3))
    velocity = np.full((JOINT_COUNT, 3), 2.0)
    velocity[3] = np.nan
    motion = PersonMotion(velocity, np.zeros_like(velocity), np.zeros_like(velocity))
    carried = carried_by_motion(joints, motion, 1.0, 1.01)
    np.testing.assert_allclose(carried[3], 1.0)
    np.testing.assert_allclose(carried[0], 1.02)
    np.testing.assert_allclose(carried_by_motion(joints, None, 1.0, 1.01), joints)
    with pytest.raises(ValueError, match="before"):
        carried_by_motion(joints, motion, 1.0, 0.99)


def test_a_mirrored_body_gets_its_persons_motion_with_sides_swapped() -> None:
    """Two sensors see one person walking; sensor b's body is remembered as mirrored (the
    pipeline swapped its left and right): its motion is the person's, left and right swapped."""
    pipeline = FusionPipeline(
        FusionSettings(
            smoothing=SmoothingSettings(filter="kalman"), bones=BoneSettings(enforce=False)
        )
    )
    for n in range(10):
        t = T0 + n * P
        world = walker(t)
        world[:, 2] = np.linspace(0.0, 0.5, JOINT_COUNT) * (t - T0)  # every joint its own speed
        pipeline.update([View("a", 1, world, full_states()), View("b", 4, world, full_states())], t)
    (person_id,) = pipeline.memories
    pipeline.memories[person_id].labels[("b", 4)] = True
    motions = track_motions(pipeline)
    straight, swapped = motions[("a", 1)], motions[("b", 4)]
    assert np.isfinite(straight.velocity).all()
    np.testing.assert_array_equal(swapped.velocity, straight.velocity[list(MIRROR_PERMUTATION)])
    assert not np.array_equal(swapped.velocity, straight.velocity)


# --- through the hub ----------------------------------------------------------------------------


def walker(t_s: float, stop_s: float = math.inf) -> np.ndarray:
    """A vertical line of joints moving sideways at 1 m/s from x = 0 at T0, standing still from
    ``stop_s`` on (world frame, metres)."""
    joints = np.zeros((JOINT_COUNT, 3))
    joints[:, 1] = np.linspace(0.1, 1.7, JOINT_COUNT)
    joints[:, 0] = min(t_s, stop_s) - T0
    return joints


def full_states() -> np.ndarray:
    return np.full(JOINT_COUNT, 2, np.uint8)


def drive(fusion: FusionSettings, periods: int, stop_s: float = math.inf) -> list[FusedFrame]:
    """Sensor a captures on the phase-0 grid, b 15 ms later; each delivered in 2 ms; the hub's
    deadline honoured as the live loop's timer does (``fuse_step`` at ``due_s``)."""
    hub = FusionHub(Settings(fusion=fusion))
    for name, pose in POSES.items():
        hello = Hello(name, "sim", "test", 30.0, 0, pose_hint=pose, pose_hint_source="sim_truth")
        hub.handle_message(name.encode(), [encode(hello)], T0, 0.0)
    base = math.floor(T0 / P) * P + 1.0
    fused = []
    for n in range(periods):
        for name, offset in (("a", 0.0), ("b", 0.015)):
            capture = base + n * P + offset
            while (due := hub.alignment.due_s) is not None and due <= capture + DELIVERY_S:
                fused.append(hub.fuse_step(due))
            world = walker(capture, stop_s)
            pose = POSES[name]
            local = (np.linalg.inv(pose) @ np.c_[world, np.ones(JOINT_COUNT)].T).T[:, :3]
            body = Body(1, local.astype(np.float32), full_states())
            frame = Frame(n + 1, int(capture * 1e9), (body,))
            received = capture + DELIVERY_S
            hub.handle_message(name.encode(), [encode(frame)], received, received - T0)
            fused.append(hub.fuse_step(received))
    return [f for f in fused if f is not None]


def late_view(frame: FusedFrame) -> np.ndarray:
    (view,) = [v for v in frame.raw if v.sensor_id == "b"]
    return view.joints_world


TRACK = FusionSettings(
    alignment=AlignmentSettings(
        policy="deadline", predictor="track", grid="wait", skip_expected_late=False
    ),
    smoothing=SmoothingSettings(filter="kalman_ca"),
    bones=BoneSettings(enforce=False),
)
"""b late at every instant (the wait grid, just before a)."""


def test_a_late_view_carried_by_its_persons_motion_lands_on_a_constant_velocity_line() -> None:
    """Once the person's filter has settled on the walker's 1 m/s, b's late view is exactly
    where the walker is at the instant (its frame 18 ms older), and the frame says so."""
    fused = drive(TRACK, periods=90)
    late = [f for f in fused if f.extrapolated and f.t_s > T0 + 2.0]
    assert len(late) >= 25
    for frame in late:
        ((sensor, behind),) = frame.extrapolated
        assert sensor == "b" and behind == pytest.approx(P - 0.015, abs=0.001)
        np.testing.assert_allclose(late_view(frame), walker(frame.t_s - DELIVERY_S), atol=1e-4)
    held = drive(replace(TRACK, smoothing=replace(TRACK.smoothing, filter="none")), 90)
    off = [np.abs(late_view(f) - walker(f.t_s - DELIVERY_S)).max() for f in held if f.extrapolated]
    assert min(off[5:]) > 0.015, "without a filter there is no motion: held, 18 mm behind"


def test_a_sudden_stop_is_overshot_until_the_filter_sees_it() -> None:
    """The predictor's failing case: the walker stops dead; the person's filter still says 1 m/s,
    so b's late view is carried on past where the walker stands (by up to v·18 ms), and comes
    back once the filter has seen the stop."""
    stop = math.floor(T0 / P) * P + 1.0 + 2.0 + 0.005
    fused = drive(TRACK, periods=150, stop_s=stop)
    after = [f for f in fused if f.extrapolated and f.t_s > stop + 0.02]
    errors = [float(np.abs(late_view(f) - walker(f.t_s, stop)).max()) for f in after]
    assert errors[0] > 0.008, "carried on at the old speed"
    assert max(errors) <= 0.0185 + 1e-4, "never more than the old speed times the horizon"
    assert errors[-1] < 0.001, "settled once the filter has seen the stop"


# --- the grid for the shortest extrapolation ----------------------------------------------------


def test_replayed_horizons_count_the_late_sensors_squared_horizons() -> None:
    # Captures 0 and 15 ms into the period, delivered in 2 ms, deadline 10 ms. A grid at 11 ms:
    # b is 4 + 2 ms after it (on time), a's frame before it 11 ms old (late). At 0.5 ms: a is
    # 33.3 − 0.5 ms ahead (late, 0.5 ms old), b 14.5 + 2 ms (late, 18.8 ms old).
    captures = np.array([[0.0] * 3, [0.015] * 3])
    cost, waits, shares = replayed_horizons(
        np.array([0.011, 0.0005]), captures, np.full((2, 3), DELIVERY_S), np.full(2, P), 0.010
    )
    np.testing.assert_allclose(cost, [0.011**2, 0.0005**2 + (P - 0.0145) ** 2])
    np.testing.assert_allclose(waits, [0.006, 0.0])
    np.testing.assert_array_equal(shares, [[1.0, 0.0], [1.0, 1.0]])


def run_policy(policy: Alignment, periods: int = 90) -> list[tuple[float, float, tuple[str, ...]]]:
    """a captures at phase 0, b 15 ms later, each delivered in 2 ms; the deadline honoured as
    the live loop's timer does. (arrival or timer, instant, late sensors) per fused instant."""
    base = math.floor(T0 / P) * P
    events = sorted(
        (base + n * P + offset + DELIVERY_S, sensor, base + n * P + offset)
        for n in range(periods)
        for sensor, offset in (("a", 0.0), ("b", 0.015))
    )
    newest: dict[str, float] = {}
    out = []
    for arrival, sensor, capture in events:
        while (due := policy.due_s) is not None and due <= arrival:
            timings = [SensorTiming(s, t, P) for s, t in newest.items()]
            if (instant := policy.next_instant(timings, due)) is not None:
                out.append((due, instant.t_s, tuple(s for s, _ in instant.late)))
        newest[sensor] = capture
        timings = [SensorTiming(s, t, P) for s, t in newest.items()]
        if (instant := policy.next_instant(timings, arrival)) is not None:
            out.append((arrival, instant.t_s, tuple(s for s, _ in instant.late)))
    return out


def test_the_horizon_grid_carries_late_sensors_less_and_fuses_without_waiting_for_them() -> None:
    """With a 10 ms deadline, b 15 ms after a: the wait grid goes just before a (b late, its
    frame 18 ms old, every instant at the deadline); the horizon grid goes 4 ms before b (b on
    time, a's frame 11 ms old) and, a being late anyway, each instant is fused as b arrives:
    6 ms after it."""
    settled = T0 + 2.0
    wait_grid = run_policy(Alignment("deadline", 30.0, deadline_s=0.010))
    horizon = Alignment("deadline", 30.0, deadline_s=0.010, grid="horizon", skip_expected_late=True)
    horizon_grid = run_policy(horizon)
    assert horizon.expected_late == {"a"}
    assert (0.015 - horizon.phase_s) % P == pytest.approx(0.004, abs=1e-6)
    for rows, wait, late in ((wait_grid, 0.010, ("b",)), (horizon_grid, 0.006, ("a",))):
        rows = [row for row in rows if row[1] > settled]
        assert len(rows) >= 25, "still one instant per period"
        for fused_at, instant, late_sensors in rows:
            assert fused_at - instant == pytest.approx(wait, abs=1e-6)
            assert late_sensors == late


def test_with_every_sensor_expected_late_the_timer_is_still_the_deadline() -> None:
    """Not the instant itself: the frames captured just before it would not be in yet (a live
    sensor captured 0.5 ms before the instant was left out, beyond the bound, at every other
    instant: 15 fused frames/s), and at the deadline they are, carried least."""
    policy = Alignment("deadline", 30.0, deadline_s=0.010, grid="horizon", skip_expected_late=True)
    run_policy(policy)
    t = policy.phase_s + math.ceil((T0 + 5.0 - policy.phase_s) / P) * P
    timings = [SensorTiming("a", t - 0.011, P), SensorTiming("b", t - 0.020, P)]
    resync = policy.next_instant(timings, t - 0.001)  # (the phase is re-chosen here too)
    assert resync is not None and resync.t_s == pytest.approx(t - P), "the grid resumes"
    policy.expected_late = frozenset({"a", "b"})  # as a rig whose sensors all come too late
    assert policy.next_instant(timings, t + 0.009) is None, "not before the deadline"
    assert policy.due_s == pytest.approx(t + 0.010), "the loop's timer: the deadline"
    instant = policy.next_instant(timings, t + 0.010)
    assert instant is not None and instant.t_s == pytest.approx(t)
    assert policy.due_s == pytest.approx(t + P + 0.010), "the next one at its own deadline"


def test_the_new_fields_do_not_change_aligned_or_phased() -> None:
    for name in ("aligned", "phased"):
        plain = Alignment(name, 30.0)  # type: ignore[arg-type]
        tuned = Alignment(name, 30.0, grid="horizon", skip_expected_late=True)  # type: ignore[arg-type]
        assert run_policy(plain) == run_policy(tuned)


def test_the_hub_under_the_default_deadline_settings_uses_the_horizon_grid() -> None:
    """``alignment = "deadline"`` with the other fields left alone: once the phase is chosen, a
    (15 ms before b) is the late one, carried 11 ms, and each instant is fused as b arrives: 4 ms
    after it (the one-way clock mapping puts b's capture at its arrival: no delivery delay)."""
    fused = drive(
        FusionSettings(
            alignment=AlignmentSettings(policy="deadline"), bones=BoneSettings(enforce=False)
        ),
        periods=90,
    )
    settled = [f for f in fused if f.t_s > T0 + 2.5]
    assert len(settled) >= 25
    for frame in settled:
        ((sensor, behind),) = frame.extrapolated
        assert sensor == "a" and behind == pytest.approx(0.011, abs=1e-4)
        assert frame.fused_at_s - frame.t_s == pytest.approx(0.004, abs=1e-4)


# --- the ``views`` predictor: what the on-time views saw meanwhile -------------------------------


VIEWS = replace(TRACK, alignment=replace(TRACK.alignment, predictor="views"))
"""b late at every instant, carried by a's views."""


def test_measured_displacements_average_the_persons_on_time_views_per_joint() -> None:
    """Person 7 is seen by a (straight) and c (mirror label set): their motions between the two
    times are averaged in the late body's order, c's sides swapped back; an Inferred joint's
    motion is not used, a joint neither has Tracked is NaN, a body of no person is absent."""
    rng = np.random.default_rng(3)
    then_a, moved_a, then_c, moved_c = (rng.normal(size=(JOINT_COUNT, 3)) for _ in range(4))
    states_c = full_states()
    states_c[5] = 1  # Inferred at the instant: c's motion of joint 5 is not a measurement
    then = {
        ("a", 1): View("a", 1, then_a, full_states()),
        ("c", 2): View("c", 2, then_c, full_states()),
    }
    now = {("a", 1): View("a", 1, then_a + moved_a, full_states()),
           ("c", 2): View("c", 2, then_c + moved_c, states_c)}  # fmt: skip
    now[("a", 1)].joints_world[9] = np.nan  # a lost joint 9 at the instant
    members = {("a", 1): (7, False), ("c", 2): (7, True), ("b", 3): (7, False)}
    out = measured_displacements([("b", 3), ("b", 4)], members, then, now)
    assert set(out) == {("b", 3)}, "b 4 was nobody at the last step"
    mirror = list(MIRROR_PERMUTATION)
    c_in_b_order = moved_c[mirror]
    c_tracked = np.ones(JOINT_COUNT, bool)
    c_tracked[mirror.index(5)] = False  # joint 5 of c is joint mirror⁻¹(5) in b's order
    expected = np.where(c_tracked[:, None], (moved_a + c_in_b_order) / 2, moved_a)
    expected[9] = np.where(c_tracked[9], c_in_b_order[9], np.nan)
    np.testing.assert_allclose(out[("b", 3)], expected, atol=1e-12)


def test_measured_displacements_for_many_persons_are_each_persons_own_mean_to_the_bit() -> None:
    """Six persons seen by up to five views each, in interleaved order, some views mirrored,
    some joints unseen or Inferred: every person's displacement is the mean over its own views
    alone, computed person by person (the reference), to the bit."""
    rng = np.random.default_rng(11)
    mirror = np.array(MIRROR_PERMUTATION)
    then: dict[tuple[str, int], View] = {}
    now: dict[tuple[str, int], View] = {}
    members: dict[tuple[str, int], tuple[int, bool]] = {}
    for sensor in "acdefg":
        for person in rng.permutation(6)[: rng.integers(2, 7)].tolist():
            key = (sensor, person)
            joints = rng.normal(size=(JOINT_COUNT, 3))
            joints[rng.integers(JOINT_COUNT)] = np.nan
            states = full_states()
            states[rng.integers(JOINT_COUNT)] = 1
            then[key] = View(sensor, person, joints, full_states())
            now[key] = View(sensor, person, joints + rng.normal(size=(JOINT_COUNT, 3)), states)
            members[key] = (person, bool(rng.random() < 0.4))
    late = [("b", person) for person in range(7)]
    members.update({key: (key[1], key[1] % 2 == 0) for key in late})
    out = measured_displacements(late, members, then, now)
    seen_persons = {person for key, (person, _) in members.items() if key[0] != "b"}
    assert set(out) == {key for key in late if key[1] in seen_persons}, "person 6: nobody saw"
    for key, got in out.items():
        rows = [k for k in now if k[0] != "b" and members[k][0] == key[1]]
        moved = []
        for k in rows:
            tracked = (now[k].states == 2) & (then[k].states == 2)
            row = np.where(tracked[:, None], now[k].joints_world - then[k].joints_world, np.nan)
            moved.append(row[mirror] if members[k][1] != members[key][1] else row)
        stacked = np.array(moved)
        finite = np.isfinite(stacked)
        count = finite.sum(axis=0)
        expected = np.where(
            count > 0, np.where(finite, stacked, 0.0).sum(axis=0) / np.maximum(count, 1), np.nan
        )
        assert np.array_equal(got, expected, equal_nan=True), key


@pytest.mark.parametrize("usual", [False, True])
@pytest.mark.parametrize("seed", range(12))
def test_the_live_paths_measurement_on_arrays_is_the_views_rule_to_the_bit(
    seed: int, usual: bool
) -> None:
    """What views_with_late runs (measured_from_arrays, rows gathered by key from the sensors'
    arrays) against measured_displacements on the same bodies as views: bodies seen at only
    one of the two times, bodies of no person, late bodies of nobody, some unseen or Inferred
    joints; the same numbers, NaN rows for the late bodies without a measurement. ``usual``:
    every on-time body at both times and of a person (the rows taken as they are)."""
    rng = np.random.default_rng(200 + seed)

    def sensor_bodies(sensor: str, ids: list[int], states: np.ndarray) -> SensorBodies:
        world = rng.normal(size=(len(ids), JOINT_COUNT, 3))
        world[rng.random(world.shape[:2]) < 0.05] = np.nan
        arrays = BodyArrays(ids, world.astype(np.float32), states)
        state = SensorState(sensor, "kinect_v2", "t", b"r", 30.0)
        return SensorBodies(state, np.eye(4), arrays, world)

    def states_of(count: int) -> np.ndarray:
        states = np.full((count, JOINT_COUNT), 2, np.uint8)
        states[rng.random(states.shape) < 0.1] = 1
        return states

    now, then = [], []
    for sensor in "acd":
        ids = [int(i) for i in rng.permutation(8)[: rng.integers(1, 6)]]
        now.append(sensor_bodies(sensor, ids, states_of(len(ids))))
        kept = [i for i in ids if usual or rng.random() < 0.8] or ids[:1]  # some only now
        then.append(sensor_bodies(sensor, kept, states_of(len(kept))))
    late_ids = [int(i) for i in rng.permutation(9)[:5]]
    newest = [sensor_bodies("b", late_ids, states_of(len(late_ids)))]
    members = {
        (b.sensor.sensor_id, i): (int(rng.integers(0, 4)), bool(rng.random() < 0.4))
        for b in now + newest
        for i in b.bodies.tracking_ids
        if rng.random() < 0.85 or (usual and b.sensor.sensor_id != "b")  # some were nobody
    }

    def views(bodies: list[SensorBodies]) -> dict[tuple[str, int], View]:
        return {
            (b.sensor.sensor_id, i): View(b.sensor.sensor_id, i, b.world[k], b.bodies.states[k])
            for b in bodies
            for k, i in enumerate(b.bodies.tracking_ids)
        }

    late_keys = [("b", i) for i in late_ids]
    want = measured_displacements(late_keys, members, views(then), views(now))
    got = measured_from_arrays(newest, members, now, then)
    # As views_with_late passes them: the rows resolve computed, now's then then's.
    stacked = (
        np.concatenate([b.world for b in now + then]),
        np.concatenate([b.bodies.states for b in now + then]),
    )
    assert measured_from_arrays(newest, members, now, then, stacked).tobytes() == got.tobytes()
    assert got.shape == (len(late_ids), JOINT_COUNT, 3)
    for row, key in enumerate(late_keys):
        if key in want:
            assert got[row].tobytes() == want[key].tobytes(), key
        else:
            assert np.isnan(got[row]).all(), key


def test_a_late_view_carried_by_the_on_time_views_needs_no_filter() -> None:
    """b's frame is 18 ms old at every instant; a, on time, saw the walker move meanwhile:
    carried by that, b's view is exactly where the walker is, with the filter off (no motion
    estimate at all: the ``track`` predictor holds it 18 mm behind)."""
    for fusion in (VIEWS, replace(VIEWS, smoothing=replace(VIEWS.smoothing, filter="none"))):
        late = [f for f in drive(fusion, periods=90) if f.extrapolated and f.t_s > T0 + 2.0]
        assert len(late) >= 25
        for frame in late:
            np.testing.assert_allclose(late_view(frame), walker(frame.t_s - DELIVERY_S), atol=1e-4)


def test_a_sudden_stop_is_not_overshot_by_the_views_predictor() -> None:
    """Where ``track`` carries b on at the old speed after the walker stops (over 8 mm: the
    filter has not seen the stop), a's views show it at once: b's view is off only at the first
    instant after the stop, by a's own interpolation across the stop, and exact after."""
    stop = math.floor(T0 / P) * P + 1.0 + 2.0 + 0.005
    fused = drive(VIEWS, periods=150, stop_s=stop)
    after = [f for f in fused if f.extrapolated and f.t_s > stop + 0.02]
    assert len(after) >= 25
    errors = [float(np.abs(late_view(f) - walker(f.t_s - DELIVERY_S, stop)).max()) for f in after]
    assert errors[0] < 0.003
    assert max(errors[1:]) < 1e-4


def test_no_deadline_until_the_grid_has_its_phase() -> None:
    """``wait_for_phase`` (the default setting): for the first second, before every sensor has
    30 frames and the grid its phase, each instant waits for both sensors (no timer, nobody
    carried); from then on the deadline applies as before. Without it, the first instants are
    already fused at the deadline, on the grid the first frames put."""
    assert FusionSettings().alignment.wait_for_phase
    waiting = Alignment("deadline", 30.0, deadline_s=0.010, wait_for_phase=True)
    rows = run_policy(waiting)
    first = [row for row in rows if row[1] < T0 + 0.9]
    assert len(first) >= 20
    assert all(late == () for _, _, late in first), "nobody carried before the phase"
    settled = [row for row in rows if row[1] > T0 + 2.0]
    assert len(settled) >= 25 and all(late == ("b",) for _, _, late in settled)
    eager = run_policy(Alignment("deadline", 30.0, deadline_s=0.010))
    assert any(late for _, instant, late in eager if instant < T0 + 0.9)


def test_sensors_late_by_different_amounts_are_each_carried_their_own_horizon() -> None:
    """a on time (frames 20 ms before and 13 ms after the instant), b late by 18 ms, c by 6 ms,
    one walker at 1 m/s: the on-time views are measured once over b's 18 ms, c carried 6/18 of
    it; both land where the walker is at the instant."""
    t = T0 + 1.0
    sensors = []
    for name, captures in (("a", (t - 0.020, t + 0.013)), ("b", (t - 0.051, t - 0.018)),
                           ("c", (t - 0.039, t - 0.006))):  # fmt: skip
        sensor = SensorState(name, "kinect_v2", "test", name.encode(), 30.0)
        for n, capture in enumerate(captures):
            body = Body(1, walker(capture).astype(np.float32), full_states())
            sensor.frames.append(TimedFrame(capture, Frame(n + 1, int(capture * 1e9), (body,))))
        sensors.append(sensor)
    members = {("a", 1): (7, False), ("b", 1): (7, False), ("c", 1): (7, False)}
    views = views_with_late(
        sensors,
        lambda _: np.eye(4),
        t,
        0.1,
        {"b": 0.018, "c": 0.006},
        (),
        LatePredictor({}, members),
    )
    assert [v.sensor_id for v in views] == ["a", "b", "c"]
    for view in views:
        np.testing.assert_allclose(view.joints_world, walker(t), atol=1e-5)
    held = views_with_late(sensors, lambda _: np.eye(4), t, 0.1, {"b": 0.018, "c": 0.006}, (),
                           LatePredictor({}))  # fmt: skip
    assert abs(held[1].joints_world[0, 0] - walker(t)[0, 0]) > 0.017, "no motion known: held"
