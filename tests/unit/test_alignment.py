"""When the hub fuses an output instant (fusion/alignment.py), driven by a clock of the test's
own: ``aligned`` waits for everyone, ``deadline`` fuses at its deadline with late sensors
extrapolated a bounded amount (or left out), the phased grid follows the sensors' capture phases;
the late sensors' extrapolation (fusion/extrapolation.py), its mark in the feed, and the live
fusion loop waking on the deadline (server/ingest.py)."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skelfuse.fusion import alignment
from skelfuse.fusion.alignment import (
    Alignment,
    Instant,
    SensorTiming,
    circular_phase,
    delay_spread,
    replayed_horizons,
    replayed_waits,
)
from skelfuse.fusion.config import FusionConfigError, fusion_settings_from_mapping
from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.extrapolation import extrapolated_bodies
from skelfuse.fusion.sensors import TimedFrame
from skelfuse.fusion.settings import AlignmentSettings, BoneSettings, SmoothingSettings
from skelfuse.protocol.feed import frame_json
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.recording.replay import replay
from skelfuse.server.broadcast import Broadcaster
from skelfuse.server.hub import FusionHub
from skelfuse.server.ingest import IDLE_WAKE_S, fusion_loop, wake_in_s
from skelfuse.server.settings import FusionSettings, Settings

P = 1 / 30
T0 = 1_800_000_000.0


def timing(sensor_id: str, newest_s: float) -> SensorTiming:
    return SensorTiming(sensor_id, newest_s, P)


# --- the policy -------------------------------------------------------------------------------


def primed(policy: Alignment, t: float) -> Alignment:
    """``policy`` having fused the grid instant before ``t`` (the first call starts the grid
    at the newest fusable instant)."""
    before = [timing("a", t - P + 0.001), timing("b", t - P + 0.002)]
    instant = policy.next_instant(before, t - P + 0.003)
    assert instant is not None and instant.t_s == pytest.approx(t - P)
    return policy


def test_aligned_waits_for_every_sensor_on_the_phase_0_grid() -> None:
    t = math.floor(T0 / P) * P  # a grid instant
    policy = primed(Alignment("aligned", 30.0), t)
    assert policy.next_instant([timing("a", t + 0.010), timing("b", t - 0.005)], t + 1) is None
    instant = policy.next_instant([timing("a", t + 0.010), timing("b", t + 0.001)], t + 1)
    assert instant is not None and instant.t_s == t and not instant.late
    assert policy.due_s is None, "aligned has no deadline"


def test_deadline_fires_with_one_sensor_late_and_marks_it() -> None:
    t = math.floor(T0 / P) * P
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.010, max_extrapolation_s=0.034), t)
    on_time, late = timing("a", t + 0.002), timing("b", t - 0.012)
    assert policy.next_instant([on_time, late], t + 0.004) is None, "before the deadline: wait"
    assert policy.due_s == pytest.approx(t + 0.010), "the loop's timer: the instant's deadline"
    assert policy.next_instant([on_time, late], t + 0.0099) is None
    instant = policy.next_instant([on_time, late], t + 0.010)
    assert instant is not None and instant.t_s == pytest.approx(t)
    ((sensor, behind),) = instant.late
    assert sensor == "b" and behind == pytest.approx(0.012, abs=1e-6) and not instant.left_out
    assert policy.due_s == pytest.approx(t + P + 0.010), "the next instant's deadline"


def test_deadline_fuses_at_once_when_everyone_is_on_time() -> None:
    t = math.floor(T0 / P) * P
    policy = primed(Alignment("deadline", 30.0), t)
    policy.next_instant([timing("a", t + 0.002), timing("b", t - 0.012)], t + 0.004)
    instant = policy.next_instant([timing("a", t + 0.002), timing("b", t + 0.001)], t + 0.004)
    assert instant is not None and instant.t_s == pytest.approx(t) and not instant.late


def test_a_sensor_beyond_the_extrapolation_bound_is_left_out() -> None:
    t = math.floor(T0 / P) * P
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.010, max_extrapolation_s=0.020), t)
    policy.next_instant([timing("a", t + 0.002), timing("b", t - 0.025)], t + 0.004)
    instant = policy.next_instant(
        [timing("a", t + 0.002), timing("b", t - 0.025), timing("c", t - 0.019)], t + 0.011
    )
    assert instant is not None
    assert instant.left_out == ("b",) and [s for s, _ in instant.late] == ["c"]


def test_a_sensor_stamped_ahead_of_the_clock_does_not_fuse_the_instant_before_it_comes() -> None:
    """A camera whose frames are stamped after they arrive (a lag nobody calibrated) has the
    instant "in" long before the server clock reaches it; with the others expected late, fusing
    then left them out (further behind than the bound): the live lag test's rig did this."""
    t = math.floor(T0 / P) * P
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.007, skip_expected_late=True), t)
    policy.expected_late = frozenset({"a"})
    ahead = timing("c", t + 0.010)  # captured at t - 0.030, stamped 40 ms late
    assert policy.next_instant([timing("a", t - 0.040), ahead], t - 0.029) is None
    assert policy.due_s == pytest.approx(t), "the loop's timer: the instant itself"
    instant = policy.next_instant([timing("a", t - 0.006), ahead], t)
    assert instant is not None and instant.t_s == pytest.approx(t) and not instant.left_out
    assert [s for s, _ in instant.late] == ["a"]


def test_an_expected_late_sensor_is_waited_for_until_its_frame_before_the_instant_is_in() -> None:
    """Not waited for past the instant, an expected-late sensor's frame from just *before* it
    is: fused as soon as the others were in, a sensor captured 2 ms before the instant whose
    frame takes 4 ms to arrive had only the frame before that, 35.3 ms behind, beyond the 34 ms
    bound: left out of every instant (CI's live lag test: 313 of 361 frames without cam-a)."""
    t = math.floor(T0 / P) * P
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.007, skip_expected_late=True), t)
    policy.expected_late = frozenset({"a"})
    in_time = timing("b", t + 0.001)
    previous = timing("a", t - 0.002 - P)  # its frame captured at t - 2 ms is on its way
    assert policy.next_instant([previous, in_time], t + 0.0012) is None, "a is not within reach"
    assert policy.due_s == pytest.approx(t + 0.007), "at the latest at the deadline"
    instant = policy.next_instant([timing("a", t - 0.002), in_time], t + 0.002)
    assert instant is not None and instant.t_s == pytest.approx(t) and not instant.left_out
    ((sensor, behind),) = instant.late
    assert sensor == "a" and behind == pytest.approx(0.002, abs=1e-6)
    # Within the bound already (captured 20 ms before): fused as soon as the others are in.
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.007, skip_expected_late=True), t)
    policy.expected_late = frozenset({"a"})
    instant = policy.next_instant([timing("a", t - 0.020), in_time], t + 0.0012)
    assert instant is not None and [s for s, _ in instant.late] == ["a"]
    # Its frame held up past the deadline: left out then, as any sensor beyond the bound.
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.007, skip_expected_late=True), t)
    policy.expected_late = frozenset({"a"})
    assert policy.next_instant([previous, in_time], t + 0.005) is None
    instant = policy.next_instant([previous, in_time], t + 0.007)
    assert instant is not None and instant.left_out == ("a",)


def test_a_sensor_expected_on_time_gets_the_grace_after_the_deadline() -> None:
    """On a link with a little jitter a sensor expected on time misses the deadline by a hair
    at random; carried from its frame before, it would be extrapolated most of a period. The
    instant waits up to the grace for it, and no longer."""
    t = math.floor(T0 / P) * P

    def policy_with(grace_s: float) -> Alignment:
        policy = Alignment(
            "deadline", 30.0, deadline_s=0.007, skip_expected_late=True, deadline_grace_s=grace_s
        )
        policy = primed(policy, t)
        policy.expected_late = frozenset({"c"})
        return policy

    on_time, expected_late = timing("a", t + 0.001), timing("c", t - 0.010)
    behind = timing("b", t + 0.004 - P)  # its frame captured at t + 4 ms is on its way
    sensors = [on_time, behind, expected_late]
    policy = policy_with(0.003)
    assert policy.next_instant(sensors, t + 0.005) is None
    assert policy.due_s == pytest.approx(t + 0.007)
    assert policy.next_instant(sensors, t + 0.007) is None, "the deadline: b gets the grace"
    assert policy.due_s == pytest.approx(t + 0.010), "the loop's timer: the grace's end"
    # b's frame comes 1 ms after the deadline: fused at once, b interpolated, not carried.
    instant = policy.next_instant([on_time, timing("b", t + 0.004), expected_late], t + 0.008)
    assert instant is not None and instant.t_s == pytest.approx(t)
    assert [s for s, _ in instant.late] == ["c"], "only the sensor expected late is carried"
    # b's frame held up past the grace as well: carried then, as at a deadline.
    policy = policy_with(0.003)
    assert policy.next_instant(sensors, t + 0.007) is None
    assert policy.next_instant(sensors, t + 0.0099) is None
    instant = policy.next_instant(sensors, t + 0.010)
    assert instant is not None and sorted(s for s, _ in instant.late) == ["b", "c"]
    assert policy.due_s == pytest.approx(t + P + 0.007), "the next instant's deadline"
    # Only sensors expected late missing: not waited for at all, as before.
    policy = policy_with(0.003)
    policy.expected_late = frozenset({"b", "c"})
    instant = policy.next_instant(sensors, t + 0.005)
    assert instant is not None and sorted(s for s, _ in instant.late) == ["b", "c"]
    # Without skip_expected_late nobody is judged expected on time: no grace.
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.007, deadline_grace_s=0.003), t)
    assert policy.next_instant(sensors, t + 0.005) is None
    instant = policy.next_instant(sensors, t + 0.007)
    assert instant is not None and sorted(s for s, _ in instant.late) == ["b", "c"]
    # 0: no grace (the rule before).
    policy = policy_with(0.0)
    instant = policy.next_instant(sensors, t + 0.007)
    assert instant is not None and sorted(s for s, _ in instant.late) == ["b", "c"]


def test_the_grace_is_a_deadline_setting_and_checked() -> None:
    assert FusionSettings().alignment.deadline_grace_s == 0.003
    phased = Alignment.of(FusionSettings(alignment=AlignmentSettings(policy="phased")), 30.0)
    assert phased.deadline_grace_s == 0.0, "phased has no deadline to extend"
    assert Alignment.of(FusionSettings(), 30.0).deadline_grace_s == 0.003
    for value in (-0.001, 0.2):
        with pytest.raises(FusionConfigError, match=r"alignment\.deadline_grace_s"):
            fusion_settings_from_mapping({"alignment": {"deadline_grace_s": value}})


def test_an_instant_nobody_can_give_waits_for_the_first_frame_not_fused_empty() -> None:
    """Every sensor's frames held up beyond the bound (a busy machine delaying every agent):
    the instant is neither published empty nor skipped; it waits, with no timer (the loop
    cannot spin), for the first frame, as ``phased`` would (CI, under load, lost 14 of 74
    instants in 2.5 s to skips: 24 frames/s from two 30 fps sensors)."""
    t = math.floor(T0 / P) * P
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.010, max_extrapolation_s=0.020), t)
    held_up = [timing("a", t - 0.05), timing("b", t - 0.03)]
    assert policy.next_instant(held_up, t + 0.011) is None
    assert policy.due_s is None, "no timer: it waits for a frame"
    assert policy.next_instant(held_up, t + 0.030) is None
    # b's next frame (captured 3 ms after its last, 45 ms late) brings it within the bound.
    instant = policy.next_instant([timing("a", t - 0.05), timing("b", t - 0.003)], t + 0.045)
    assert instant is not None and instant.t_s == pytest.approx(t)
    assert instant.left_out == ("a",) and [s for s, _ in instant.late] == ["b"]


def test_a_stall_beyond_two_periods_skips_to_the_newest_fusable_instant() -> None:
    t = math.floor(T0 / P) * P
    policy = primed(Alignment("deadline", 30.0, deadline_s=0.010, max_extrapolation_s=0.020), t)
    held_up = [timing("a", t - 0.05), timing("b", t - 0.03)]
    assert policy.next_instant(held_up, t + 0.011) is None
    late_by_far = [timing("a", t + 3 * P + 0.001), timing("b", t + 3 * P + 0.002)]
    instant = policy.next_instant(late_by_far, t + 3 * P + 0.004)
    assert instant is not None and instant.t_s == pytest.approx(t + 3 * P), "resynced"


def test_circular_phase_averages_across_the_wrap() -> None:
    times = [T0 + n * P + jitter for n, jitter in enumerate([-0.001, 0.001, -0.0005, 0.0005])]
    phase = circular_phase(times, P)
    assert min(phase, P - phase) < 1e-4, "phases either side of 0 average to 0, not P/2"
    with pytest.raises(ValueError, match="no times"):
        circular_phase([], P)


def test_replayed_waits_are_the_wait_for_the_last_sensor() -> None:
    # Captures at 5, 10 and 25 ms into each period, 2 ms delivery: a grid just before 25 ms
    # waits for the 10 ms sensor's next frame (P - 24.5 + 10 + 2 ms), just before 5 ms for the
    # 25 ms one, phase 0 for 25 + 2 ms.
    captures = np.array([[0.005] * 4, [0.010] * 4, [0.025] * 4])
    waits = replayed_waits(
        np.array([0.0, 0.0245, 0.0045]), captures, np.full((3, 4), 0.002), np.full(3, P)
    )
    np.testing.assert_allclose(waits, [0.027, P - 0.0245 + 0.010 + 0.002, 0.025 - 0.0045 + 0.002])


def test_a_scattered_sensor_gets_a_wider_margin() -> None:
    """Sensor b's captures scatter by ±1.5 ms (its clock mapping moves): a grid 0.5 ms before
    its mean phase lets half its frames miss the instant (a whole period more); the policy
    replays the frames and puts the grid far enough before it."""
    rng = np.random.default_rng(3)
    policy = Alignment("phased", 30.0)
    base = math.floor(T0 / P) * P
    newest: dict[str, float] = {}
    for n in range(90):
        for sensor, capture in sorted(
            (
                ("a", base + n * P + 0.030),
                ("b", base + n * P + 0.020 + rng.uniform(-1.5, 1.5) / 1e3),
            ),
            key=lambda item: item[1],
        ):
            newest[sensor] = capture
            policy.next_instant([timing(s, t) for s, t in newest.items()], capture + 0.001)
    gap = (0.020 - policy.phase_s) % P
    assert 0.001 < gap <= 0.0041, "further before b than the 0.5 ms a steady sensor gets"


def test_the_grid_phase_follows_the_sensors_and_cuts_the_wait() -> None:
    """Two sensors capture 20 and 22 ms into each phase-0 period and deliver in 2 ms: on the
    phase-0 grid every instant waits ~24 ms for the second; once the phase is estimated
    (within REPHASE_EVERY_S), ~4.5 ms."""
    waits: dict[str, list[float]] = {"aligned": [], "phased": []}
    for policy_name in waits:
        policy = Alignment(policy_name, 30.0)  # type: ignore[arg-type]
        base = math.floor(T0 / P) * P
        events = sorted(
            (base + n * P + offset + 0.002, sensor, base + n * P + offset)
            for n in range(90)
            for sensor, offset in (("a", 0.020), ("b", 0.022))
        )
        newest: dict[str, float] = {}
        for arrival, sensor, capture in events:
            newest[sensor] = capture
            instant = policy.next_instant([timing(s, t) for s, t in newest.items()], arrival)
            if instant is not None and arrival > base + 2.0:  # after the phase settled
                waits[policy_name].append(arrival - instant.t_s)
    assert np.median(waits["aligned"]) == pytest.approx(0.024, abs=1e-3)
    assert np.median(waits["phased"]) == pytest.approx(0.0045, abs=1e-3)
    assert len(waits["phased"]) >= 29, "still one instant per period"


# --- extrapolation ----------------------------------------------------------------------------


def body(tracking_id: int, value: float, state: int = 2) -> Body:
    joints = np.full((JOINT_COUNT, 3), value, np.float32)
    return Body(tracking_id, joints, np.full(JOINT_COUNT, state, np.uint8))


def timed(t: float, *bodies: Body) -> TimedFrame:
    return TimedFrame(t, Frame(int(t * 1000), int(t * 1e9), bodies))


def test_extrapolation_continues_the_motion_of_the_two_newest_frames() -> None:
    first, second = body(7, 0.0, state=1), body(7, 1.0)
    second.joints_m[4] = np.nan
    frames = deque([timed(1.0, first), timed(1.1, second)])
    (result,) = extrapolated_bodies(frames, 1.125, max_gap_s=0.2)
    np.testing.assert_allclose(result.joints_m[0], 1.25, atol=1e-6)
    assert result.states[0] == 1, "the lower state of the two"
    assert np.isnan(result.joints_m[4]).all(), "a joint missing from one frame is not invented"


def test_extrapolation_holds_when_frames_are_too_far_apart_or_alone() -> None:
    frames = deque([timed(1.0, body(7, 0.0)), timed(1.3, body(7, 1.0))])
    (held,) = extrapolated_bodies(frames, 1.32, max_gap_s=0.1)
    np.testing.assert_allclose(held.joints_m, 1.0)
    (alone,) = extrapolated_bodies(deque([timed(1.3, body(8, 2.0))]), 1.32, max_gap_s=0.1)
    np.testing.assert_allclose(alone.joints_m, 2.0)
    with pytest.raises(ValueError, match="before the newest"):
        extrapolated_bodies(frames, 1.2, max_gap_s=0.1)


# --- through the hub: provenance ---------------------------------------------------------------


def walker(t_s: float, origin_s: float = T0) -> np.ndarray:
    """A person in the middle of the room, a vertical line of joints moving sideways at 1 m/s
    from x = 0 at ``origin_s`` (world frame; each sensor is sent it in its own frame)."""
    joints = np.zeros((JOINT_COUNT, 3))
    joints[:, 1] = np.linspace(0.1, 1.7, JOINT_COUNT)
    joints[:, 0] = (t_s - origin_s) * 1.0
    return joints


POSES = {
    "a": look_at_pose((0.0, 1.0, 3.0), (0.0, 0.9, 0.0)),
    "b": look_at_pose((3.0, 1.0, 0.0), (0.0, 0.9, 0.0)),
}


def hub_with_sensors(settings: Settings) -> FusionHub:
    hub = FusionHub(settings)
    for name, pose in POSES.items():
        hello = Hello(name, "sim", "test", 30.0, 0, pose_hint=pose, pose_hint_source="sim_truth")
        hub.handle_message(name.encode(), [encode(hello)], T0, 0.0)
    return hub


def send(
    hub: FusionHub, name: str, seq: int, capture_s: float, received_s: float, origin_s: float = T0
) -> None:
    world = walker(capture_s, origin_s)
    pose = POSES[name]
    local = (np.linalg.inv(pose) @ np.c_[world, np.ones(JOINT_COUNT)].T).T[:, :3]
    states = np.full(JOINT_COUNT, 2, np.uint8)
    frame = Frame(seq, int(capture_s * 1e9), (Body(1, local.astype(np.float32), states),))
    hub.handle_message(name.encode(), [encode(frame)], received_s, received_s - T0)


def drive(hub: FusionHub, periods: int) -> list[FusedFrame]:
    """Sensor a captures on the phase-0 grid, b 15 ms later, both delivered in 2 ms; the hub's
    deadline is honoured as the live loop's timer does (fuse_step at ``due_s``)."""
    base = math.floor(T0 / P) * P + 1.0
    fused = []
    for n in range(periods):
        for name, offset in (("a", 0.0), ("b", 0.015)):
            capture = base + n * P + offset
            while (due := hub.alignment.due_s) is not None and due <= capture + 0.002:
                fused.append(hub.fuse_step(due))
            send(hub, name, n + 1, capture, capture + 0.002)
            fused.append(hub.fuse_step(capture + 0.002))
    return [f for f in fused if f is not None]


def test_a_late_sensor_is_extrapolated_to_the_instant_and_marked_in_the_feed() -> None:
    fusion = FusionSettings(
        alignment=AlignmentSettings(
            policy="deadline",
            predictor="own",
            grid="wait",
            skip_expected_late=False,
            wait_for_phase=False,
        ),
        smoothing=SmoothingSettings(filter="none"),
        bones=BoneSettings(enforce=False),
    )
    fused = drive(hub_with_sensors(Settings(fusion=fusion)), periods=60)
    late = [f for f in fused if f.extrapolated and f.persons]  # published from the 3rd frame
    assert len(late) >= 50, "b's frames come 17 ms after a's instants: after a 10 ms deadline"
    for frame in late:
        ((sensor, behind),) = frame.extrapolated
        assert sensor == "b" and 0 < behind <= fusion.alignment.max_extrapolation_s
        assert frame.fused_at_s - frame.t_s <= fusion.alignment.deadline_s + 1e-9
        (person,) = frame.persons
        # b's view carried along the line (the server's clock reads captures 2 ms late, the
        # one-way delivery): held instead, the mean would be ~9 mm behind
        np.testing.assert_allclose(person.joints[:, 0], frame.t_s - 0.002 - T0, atol=1e-3)
        message = frame_json(frame, include_raw=False)
        assert message["extrapolated"] == {"b": round(behind, 4)}
    on_time = [f for f in fused if not f.extrapolated]
    assert on_time and "extrapolated" not in frame_json(on_time[0], include_raw=False)


def test_aligned_hub_output_has_no_extrapolation_mark() -> None:
    hub = hub_with_sensors(
        Settings(fusion=FusionSettings(alignment=AlignmentSettings(policy="aligned")))
    )
    fused = drive(hub, periods=30)
    assert len(fused) >= 29 and all(f.extrapolated == () for f in fused)
    assert all(f.fused_at_s - f.t_s > 0.015 for f in fused[1:]), "waits for b"
    assert hub.alignment.due_s is None


# --- the live loop: a timer, not the next arrival ----------------------------------------------


def test_the_loop_sleeps_until_the_deadline_not_the_idle_poll() -> None:
    fusion = FusionSettings(alignment=AlignmentSettings(policy="deadline", wait_for_phase=False))
    hub = FusionHub(Settings(fusion=fusion))
    assert wake_in_s(hub, T0) == IDLE_WAKE_S, "nothing pending"
    hub.alignment.next_instant([timing("a", T0 + 0.002), timing("b", T0 - 0.02)], T0 + 0.003)
    due = hub.alignment.due_s
    assert due is not None
    assert wake_in_s(hub, due - 0.004) == pytest.approx(0.004, abs=1e-6)
    assert wake_in_s(hub, due + 0.010) == 0.0


def test_the_fusion_loop_publishes_at_the_deadline_with_no_further_frame() -> None:
    """Through the real loop and wall clock: b stops sending; a's frames are past the instant;
    nothing more arrives, and the instant is still fused, b extrapolated."""
    deadline_s = 0.02
    fusion = FusionSettings(
        alignment=AlignmentSettings(policy="deadline", deadline_s=deadline_s, wait_for_phase=False)
    )
    hub = hub_with_sensors(
        Settings(fusion=replace(fusion, smoothing=replace(fusion.smoothing, filter="none")))
    )

    async def run() -> None:
        broadcaster = Broadcaster()
        task = asyncio.create_task(fusion_loop(hub, broadcaster))
        now = time.time()
        # a has reported well past the next instants; b's newest is 5 ms old, and b goes quiet
        for seq, ahead in enumerate((-0.05, 0.1), start=1):
            send(hub, "a", seq, now + ahead, now + ahead + 0.001, origin_s=now)
        for seq, ago in enumerate((0.04, 0.005), start=1):
            send(hub, "b", seq, now - ago, now - ago + 0.001, origin_s=now)
        hub.frame_arrived.set()
        for _ in range(100):  # up to 1 s on a busy machine
            await asyncio.sleep(0.01)
            if hub.latest is not None and hub.latest.extrapolated:
                break
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(run())
    assert hub.latest is not None and [s for s, _ in hub.latest.extrapolated] == ["b"]


def test_deadline_with_the_views_predictor_is_the_default() -> None:
    # Measured (docs/benchmarks.md "Alignment policies", "Load"): within 1 mm of aligned in every
    # accuracy scenario, and the live latency target with 10 sensors at random phases.
    default = FusionSettings()
    assert default.alignment.policy == "deadline" and default.alignment.deadline_s == 0.007
    assert default.alignment.predictor == "views" and default.alignment.wait_for_phase


def test_offline_replay_always_waits_for_every_sensor() -> None:
    take = Path(__file__).resolve().parents[1] / "data" / "golden" / "take.sfrec"
    deadline = Settings(fusion=FusionSettings(alignment=AlignmentSettings(policy="deadline")))
    as_set = [frame_json(f, include_raw=False) for f in replay(take, deadline)]
    aligned = [frame_json(f, include_raw=False) for f in replay(take)]
    assert len(aligned) == 180 and as_set == aligned


def test_the_toml_settings_are_checked() -> None:
    chosen = fusion_settings_from_mapping(
        {"alignment": {"policy": "deadline", "deadline_s": 0.005, "max_extrapolation_s": 0}}
    )
    assert chosen.alignment.policy == "deadline" and chosen.alignment.max_extrapolation_s == 0.0
    with pytest.raises(FusionConfigError) as caught:
        fusion_settings_from_mapping(
            {"alignment": {"policy": "soon", "deadline_s": 0.5, "max_extrapolation_s": 1}}
        )
    message = str(caught.value)
    for key in ("alignment.policy:", "alignment.deadline_s:", "alignment.max_extrapolation_s:"):
        assert key in message


@pytest.mark.parametrize("budget", [1, 600, 7_000, 65_536])
def test_replays_in_parts_give_the_bits_of_all_at_once(
    monkeypatch: pytest.MonkeyPatch, budget: int
) -> None:
    """The waits' candidates are replayed a few at a time to keep the arrays in the cache: every
    part size (down to one candidate, and a last part shorter than the others) gives the same
    answers as one pass over all of them."""
    rng = np.random.default_rng(budget)
    phases = rng.uniform(0.0, 1 / 30, 129)
    periods = rng.choice([1 / 30, 1 / 15, 1 / 60], 16)
    captures = rng.uniform(0.0, 1 / 30, (16, 60)) % periods[:, None]
    delays = rng.uniform(0.0, 0.02, (16, 60))
    monkeypatch.setattr(alignment, "REPLAYED_AT_ONCE", 10**9)
    want_waits = replayed_waits(phases, captures, delays, periods)
    monkeypatch.setattr(alignment, "REPLAYED_AT_ONCE", budget)
    parts = alignment._parts(phases, captures)
    assert np.concatenate(parts).tobytes() == phases.tobytes()
    assert len(parts) == 129 if budget < 960 else len(parts) > 1  # every budget here splits
    assert all(len(p) * 960 <= max(budget, 960) for p in parts)
    assert replayed_waits(phases, captures, delays, periods).tobytes() == want_waits.tobytes()


@pytest.mark.parametrize("seed", range(6))
def test_replays_are_the_rule_written_plainly(seed: int) -> None:
    """The replays' answers are those of the rule written with a fresh array per step (the
    waits to the bit: they work two arrays in place), ties at the deadline and zero phases
    included."""
    rng = np.random.default_rng(seed)
    sensors, frames = int(rng.integers(1, 17)), int(rng.integers(1, 61))
    periods = rng.choice([1 / 30, 1 / 15, 1 / 60], sensors)
    captures = rng.uniform(0.0, 0.05, (sensors, frames)) % periods[:, None]
    delays = rng.uniform(0.0, 0.02, (sensors, frames))
    phases = np.concatenate([rng.uniform(0.0, 1 / 30, 40), captures[0, :3]])  # ahead = 0
    delays[0, :3] = 0.007  # seen exactly at the deadline when ahead is 0: on time
    ahead = np.mod(captures[None] - phases[:, None, None], periods[None, :, None])
    seen = ahead + delays[None]
    late = seen > 0.007
    horizon = np.where(late, periods[None, :, None] - ahead, 0.0)
    want = (
        (horizon**2).sum(axis=1).mean(axis=1),
        np.where(late, 0.0, seen).max(axis=1).mean(axis=1),
        late.mean(axis=2),
    )
    got = replayed_horizons(phases, captures, delays, periods, 0.007)
    for a, b in zip(got, want, strict=True):  # one loop: numpy's sums, within an ulp or two
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    plain_waits = (ahead + delays[None]).max(axis=1).mean(axis=1)
    assert replayed_waits(phases, captures, delays, periods).tobytes() == plain_waits.tobytes()


# --- the fall-back to phased's wait on a jittery link -------------------------------------------


@pytest.mark.parametrize("seed", range(4))
def test_circular_phase_is_the_plain_sums_to_the_bit(seed: int) -> None:
    """Each angle once and the sums taken by map: the floats of the generator sums it was."""
    rng = np.random.default_rng(seed)
    times = (T0 + np.cumsum(rng.uniform(0.03, 0.037, 60)) + rng.normal(0, 0.002, 60)).tolist()
    omega = 2.0 * math.pi / P
    c = sum(math.cos(omega * (t - times[0])) for t in times)
    s = sum(math.sin(omega * (t - times[0])) for t in times)
    plain = (times[0] + math.atan2(s, c) / omega) % P
    assert circular_phase(times, P) == plain


def test_the_delay_spread_is_numpys_percentiles_to_the_bit() -> None:
    """500 random windows (1–16 sensors, 2–60 frames, steady runs and exponential tails): the
    same floats as ``np.percentile`` and ``np.median``; about one in sixty tells numpy's
    two-sided interpolation from the one-sided one."""
    rng = np.random.default_rng(0)
    for _ in range(500):
        sensors, frames = int(rng.integers(1, 17)), int(rng.integers(2, 61))
        delays = 0.002 + rng.exponential(rng.uniform(0.0, 0.005), (sensors, frames))
        if rng.random() < 0.3:
            delays[:, : frames // 2] = 0.002  # ties, as a steady link gives
        spreads = np.percentile(delays, 90, axis=1) - np.percentile(delays, 10, axis=1)
        assert delay_spread(delays) == float(np.median(spreads))
        assert delay_spread(delays[:, ::-1]) == delay_spread(delays), "order does not matter"


class _Drive:
    """Two 30 fps sensors, captured 2 and 20 ms after the grid's phase 0, their frames seen 2 ms
    after capture plus an exponential delay; ``policy`` asked at every arrival and at its
    deadline, as the live loop does. What the sensors sent and each fused instant's wait carry
    over from one :meth:`run` to the next."""

    def __init__(self, policy: Alignment) -> None:
        self.policy = policy
        self.newest: dict[str, float] = {}
        self.waits: list[float] = []
        """Each fused instant's wait (seconds from the instant to its fusion), in order."""

    def run(self, start_s: float, seconds: float, jitter_s: float, seed: int = 0) -> list[Instant]:
        """``seconds`` of frames from ``start_s``, each delayed a further exponential amount of
        mean ``jitter_s``: the instants fused, in order."""
        rng = np.random.default_rng(seed)
        arrivals: list[tuple[float, str, float]] = []
        for k in range(round(seconds / P)):
            for sensor, phase in (("a", 0.002), ("b", 0.020)):
                capture = start_s + k * P + phase
                extra = float(rng.exponential(jitter_s)) if jitter_s > 0 else 0.0
                arrivals.append((capture + 0.002 + extra, sensor, capture))
        arrivals.sort()
        fused: list[Instant] = []

        def ask(now_s: float) -> None:
            timings = [timing(s, t) for s, t in self.newest.items()]
            while instant := self.policy.next_instant(timings, now_s):
                fused.append(instant)
                self.waits.append(now_s - instant.t_s)

        for arrival, sensor, capture in arrivals:
            due = self.policy.due_s
            if due is not None and due <= arrival and self.newest:
                ask(due)
            self.newest[sensor] = max(self.newest.get(sensor, -math.inf), capture)
            ask(arrival)
        return fused


def test_the_sensors_not_waited_for_are_those_late_at_the_phase_kept() -> None:
    """One sensor, captured at 2 ms, seen 2 ms later. Just after its phase (late by 0.5 ms:
    0.5² ms² of horizon) and just before it (0.5 + 2 ms of wait at the tie-break's weight)
    score the same, so the grid stays where it is; the sensor is expected late there, though
    not at the candidate that scored a hair better."""
    t = math.floor(T0 / P) * P
    policy = Alignment("deadline", 30.0, deadline_s=0.007, grid="horizon", skip_expected_late=True)
    policy.phase_s = 0.0025
    for k in range(40):
        capture = t + k * P + 0.002
        policy.next_instant([timing("a", capture)], capture + 0.002)
    assert policy.phase_s == 0.0025, "within the hysteresis: kept"
    assert policy.expected_late == {"a"}
    policy.phase_s = 0.0015  # just before its phase: on time there
    policy._next_rephase_s = -1.0
    capture = t + 40 * P + 0.002
    policy.next_instant([timing("a", capture)], capture + 0.002)
    assert policy.phase_s == 0.0015 and policy.expected_late == set()


def _deadline_policy(fallback_s: float) -> Alignment:
    return Alignment(
        "deadline", 30.0, deadline_s=0.007, grid="horizon", skip_expected_late=True,
        wait_for_phase=True, jitter_fallback_s=fallback_s,
    )  # fmt: skip


def test_a_jittery_link_waits_for_every_sensor_and_a_steady_one_gets_its_deadline_back() -> None:
    t = math.floor(T0 / P) * P
    policy = _deadline_policy(0.003)
    drive = _Drive(policy)
    steady = drive.run(t, 3.0, 0.0)
    assert not policy.jittery and policy.delay_spread_s == pytest.approx(0.0, abs=1e-9)
    assert any(i.late for i in steady[-30:]), "steady: the deadline carries the late sensor"
    jittery = drive.run(t + 3.0, 4.0, 0.003, seed=1)
    assert policy.jittery and policy.delay_spread_s is not None
    assert policy.delay_spread_s > 0.003
    assert f"scatter {1e3 * policy.delay_spread_s:.1f} ms" in policy.jitter_report()
    waited = jittery[-60:]
    assert waited and not any(i.late or i.left_out for i in waited), "phased: nobody carried"
    assert policy.due_s is None, "no deadline timer while jittery"
    # On phased's grid, not the deadline's (which may sit just after a sensor's phase): the
    # same wait as phased on the same arrivals.
    phased = _Drive(Alignment("phased", 30.0))
    phased.run(t, 3.0, 0.0)
    phased.run(t + 3.0, 4.0, 0.003, seed=1)
    assert np.mean(drive.waits[-60:]) == pytest.approx(np.mean(phased.waits[-60:]), abs=0.001)
    settled = drive.run(t + 7.0, 4.0, 0.0)
    assert not policy.jittery, "60 steady frames later the deadline is back"
    assert "settled (0.0 ms)" in policy.jitter_report()
    assert any(i.late for i in settled[-30:])


def test_the_fallback_has_hysteresis_and_can_be_turned_off() -> None:
    t = math.floor(T0 / P) * P
    policy = _deadline_policy(0.003)
    drive = _Drive(policy)
    drive.run(t, 4.0, 0.003, seed=2)
    assert policy.jittery
    assert policy.delay_spread_s is not None
    # Judged between the two thresholds (2 and 3 ms here): it stays as it is, either way.
    spread = policy.delay_spread_s
    policy.jitter_fallback_s = spread / 0.8  # the scatter is 80 % of the threshold
    policy._next_rephase_s = -1.0  # re-judge at the next call
    drive.run(t + 4.0, 0.1, 0.003, seed=2)
    assert policy.jittery, "above two thirds of the threshold: still waiting"
    off = _deadline_policy(0.0)
    fused = _Drive(off).run(t, 4.0, 0.003, seed=2)
    assert not off.jittery and off.delay_spread_s is None
    assert any(i.late for i in fused[-60:]), "no fall-back: the deadline carries sensors"


@pytest.mark.parametrize("value", [-0.001, 0.2])
def test_the_jitter_fallback_is_checked(value: float) -> None:
    with pytest.raises(FusionConfigError, match=r"alignment\.jitter_fallback_s"):
        fusion_settings_from_mapping({"alignment": {"jitter_fallback_s": value}})


def test_the_hub_falls_back_on_a_jittery_link_says_so_and_comes_back(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """End to end through the hub with the default settings: 3 ms of exponential delivery
    jitter takes the deadline away (no sensor carried, a log line naming the scatter), steady
    delivery brings it back (and says so)."""
    hub = hub_with_sensors(Settings())
    rng = np.random.default_rng(5)
    seq = {"a": 0, "b": 0}

    def run(start_s: float, seconds: float, jitter_s: float) -> list[FusedFrame]:
        arrivals = []
        for k in range(round(seconds / P)):
            for name, phase in (("a", 0.002), ("b", 0.020)):
                capture = start_s + k * P + phase
                extra = float(rng.exponential(jitter_s)) if jitter_s else 0.0
                arrivals.append((capture + 0.002 + extra, name, capture))
        fused: list[FusedFrame] = []
        for received, name, capture in sorted(arrivals):
            due = hub.alignment.due_s
            if due is not None and due <= received and (frame := hub.fuse_step(due)):
                fused.append(frame)
            seq[name] += 1
            send(hub, name, seq[name], capture, received)
            while frame := hub.fuse_step(received):
                fused.append(frame)
        return fused

    steady = run(T0, 3.0, 0.0)
    assert any(f.extrapolated for f in steady[-30:]), "steady: the deadline carries b"
    with caplog.at_level(logging.WARNING, logger="skelfuse.fusion.engine"):
        jittery = run(T0 + 3.0, 4.0, 0.003)
    assert any("delivery delays scatter" in r.getMessage() for r in caplog.records)
    assert not any(f.extrapolated for f in jittery[-60:]), "waiting as phased: nobody carried"
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="skelfuse.fusion.engine"):
        settled = run(T0 + 7.0, 4.0, 0.0)
    assert any("the deadline is back" in r.getMessage() for r in caplog.records)
    assert any(f.extrapolated for f in settled[-30:])
