"""Calibration runs (server/calibration_runs.py) driven by a fake clock, a real hub fed with
simulated frames, and fake agents: stages and progress as time passes, refusals, degraded and
failed runs, commit. The clock's ``sleep`` advances its own time and feeds the next frames, so
a 4 s capture takes no wall time and no test reads the wall clock."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sources.sim import SimSource
from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.solvers import PointPairs
from skelfuse.calibration.store import CalibrationStore, SensorCalibration
from skelfuse.protocol.depth_cloud import encode_reply
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, axis_rotation, invert, look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.calibration_run import CalibrationRun, RunSpec, RunState
from skelfuse.server.calibration_run_progress import PRIOR_S_PER_UNIT, SKELETONS, WALK
from skelfuse.server.calibration_runs import CalibrationService
from skelfuse.server.errors import (
    AgentRequestFailed,
    Conflict,
    InvalidRequest,
    NotFound,
    SensorUnavailable,
    SolverCrashed,
)
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings
from skelfuse.server.solver_pool import ThreadSolvers

POSES = {
    "cam-a": look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0)),
    "cam-b": look_at_pose((2.6, 1.4, -1.5), (0.0, 1.0, 0.0)),
}
PERFORMER = ProceduralPerformer(1)
START_S = 1_763_712_000.0


class FakeClock:
    """Wall and monotonic time that move only when someone sleeps; each sleep runs the hooks
    (the fake agents streaming the frames of the time that passed)."""

    def __init__(self) -> None:
        self.wall = START_S
        self.mono = 500.0
        self.hooks: list[Callable[[], None]] = []

    def time(self) -> float:
        return self.wall

    def monotonic(self) -> float:
        return self.mono

    async def sleep(self, seconds: float) -> None:
        self.wall += seconds
        self.mono += seconds
        for hook in self.hooks:
            hook()
        await asyncio.sleep(0)


class FakeAgents:
    """Answers ``depth_cloud`` with ``answer(sensor_id)`` (a result, or an exception to raise)."""

    def __init__(self, answer: Callable[[str], Any]) -> None:
        self.answer = answer
        self.asked: list[tuple[str, str, dict[str, Any]]] = []

    async def request(
        self, sensor_id: str, method: str, params: dict[str, Any], timeout_s: float
    ) -> Any:
        self.asked.append((sensor_id, method, params))
        result = self.answer(sensor_id)
        if isinstance(result, Exception):
            raise result
        return result


def floor_plane(pose: Matrix4) -> tuple[float, float, float, float]:
    """The Kinect FloorClipPlane a sensor at ``pose`` reports: world up in its frame, height."""
    up = pose[:3, :3].T @ np.array([0.0, 1.0, 0.0])
    return (float(up[0]), float(up[1]), float(up[2]), float(pose[1, 3]))


class Rig:
    """A hub with the sensors registered and streaming the walking performer at 30 Hz."""

    def __init__(self, tmp_path: Path, sensors: tuple[str, ...] = ("cam-a", "cam-b")) -> None:
        self.clock = FakeClock()
        self.hub = FusionHub(Settings())
        self.store = CalibrationStore(tmp_path)
        self.sensors = sensors
        self.silent: set[str] = set()
        self.seq = 0
        self.next_frame_s = self.clock.wall - 0.5
        for i, sensor_id in enumerate(sensors):
            hello = Hello(sensor_id, "sim", "t", 30.0, 0)
            self.hub.handle_message(bytes([i]), [encode(hello)], self.clock.wall, self.clock.mono)
        self.stream()
        self.clock.hooks.append(self.stream)

    def stream(self) -> None:
        """Every sensor's frames up to the clock's present (capture stamp = server time)."""
        while self.next_frame_s <= self.clock.wall:
            t = self.next_frame_s
            world = PERFORMER.joints_at((t - START_S) % 6.3)[0]  # the routine's walk, looped
            self.seq += 1
            for i, sensor_id in enumerate(self.sensors):
                if sensor_id in self.silent:
                    continue
                pose = POSES[sensor_id]
                states = np.full(JOINT_COUNT, TrackingState.TRACKED, np.uint8)
                body = Body(7 + i, apply(invert(pose), world).astype(np.float32), states)
                frame = Frame(self.seq, round(t * 1e9), (body,), floor_plane(pose))
                self.hub.handle_message(bytes([i]), [encode(frame)], t, self.clock.mono)
            self.next_frame_s += 1 / 30

    def service(self, agents: FakeAgents | None = None) -> CalibrationService:
        agents = agents or FakeAgents(lambda _: AgentRequestFailed("this source has no depth"))
        # In a thread: the run's timing is the fake clock's, and one test patches a solver.
        return CalibrationService(self.hub, self.store, agents, self.clock, solvers=ThreadSolvers())


async def finished(run: CalibrationRun) -> CalibrationRun:
    """Wait for the run's task (its solver runs in a worker thread)."""
    (task,) = [t for t in asyncio.all_tasks() if t.get_name() == f"calibration-{run.run_id}"]
    await task
    return run


def relative(results: dict[str, Any], a: str, b: str) -> Matrix4:
    pose_b: Matrix4 = results[b].T_world_from_sensor
    return invert(results[a].T_world_from_sensor) @ pose_b


async def test_skeleton_run_reports_stages_and_progress_by_the_clock(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    service = rig.service()
    seen: list[tuple[float, str, float]] = []
    run = service.start(RunSpec("skeleton", "cam-a", ("cam-a", "cam-b"), duration_s=4.0))
    rig.clock.hooks.append(lambda: seen.append((rig.clock.mono, run.stage, run.progress)))
    await finished(run)
    assert run.state == RunState.DONE, run.error
    capture = [(t - 500.0, p) for t, stage, p in seen if stage.startswith("walk through")]
    assert len(capture) == 120  # 4 s at 30 samples per second
    progress = [p for _, p in capture]
    # The walk's share of the bar: its 4 s against the skeleton solve's expected time (a prior
    # on a fresh server: nothing measured yet).
    share = 4.0 / (4.0 + PRIOR_S_PER_UNIT[SKELETONS])
    assert progress == sorted(progress) and progress[-1] < share
    t_half, p_half = capture[59]  # recorded as the sample's sleep ends, 1/30 s after it
    assert p_half == pytest.approx(share * (t_half - 1 / 30) / 4.0)
    assert run.progress == 1.0 and run.stage == "done"
    report = run.to_json()
    assert report["stages"] == [WALK, SKELETONS] and report["stage_index"] == 2
    assert report["eta_s"] == 0.0
    assert run.finished_unix_s == pytest.approx(START_S + 4.0, abs=0.05)
    truth = invert(POSES["cam-a"]) @ POSES["cam-b"]
    rotation_deg, translation_mm = pose_error(relative(run.results, "cam-a", "cam-b"), truth)
    assert rotation_deg < 0.5 and translation_mm < 10.0
    assert run.floor is not None and run.floor["source"] == "kinect_floor_plane"
    assert run.floor["sensor_height_m"] == pytest.approx(1.0, abs=1e-3)
    height_b = run.results["cam-b"].T_world_from_sensor[1, 3]
    assert height_b == pytest.approx(1.4, abs=0.01)  # levelled: the floor is y = 0


async def test_auto_run_keeps_the_skeleton_poses_when_an_agent_has_no_depth(
    tmp_path: Path,
) -> None:
    rig = Rig(tmp_path)
    agents = FakeAgents(lambda _: AgentRequestFailed("sensor refused 'depth_cloud'"))
    run = await finished(rig.service(agents).start(RunSpec("auto", "cam-a", rig.sensors, 3.0)))
    assert run.state == RunState.DONE, run.error
    assert any(w.startswith("no ICP refinement: sensor refused") for w in run.warnings)
    assert {r.method for r in run.results.values()} == {"reference", "skeleton"}
    assert [a[1:] for a in agents.asked] == [("depth_cloud", {"max_points": 20000})] * 2


async def test_icp_run_fails_with_the_sensor_named_when_its_cloud_is_unusable(
    tmp_path: Path,
) -> None:
    rig = Rig(tmp_path)
    stored = {sensor_id: SensorCalibration(pose, "points") for sensor_id, pose in POSES.items()}
    rig.hub.use_calibration(rig.store.save(stored))
    good = encode_reply(np.random.default_rng(0).uniform(-2, 2, (600, 3)))
    agents = FakeAgents(lambda s: good if s == "cam-a" else encode_reply(np.zeros((3, 3))))
    run = await finished(rig.service(agents).start(RunSpec("icp", "cam-a", rig.sensors)))
    assert run.state == RunState.FAILED and run.stage == "failed"
    assert run.error is not None and "'cam-b'" in run.error and "only 3 finite points" in run.error


async def test_icp_run_refines_from_the_stored_poses_and_levels_with_depth(
    tmp_path: Path,
) -> None:
    rig = Rig(tmp_path)
    off = POSES["cam-b"].copy()
    off[1, 3] += 0.04  # 40 mm too high: the shared floor pins height (not yaw, docs/calibration.md)
    stored = {"cam-a": POSES["cam-a"], "cam-b": off}
    rig.hub.use_calibration(
        rig.store.save({s: SensorCalibration(pose, "points") for s, pose in stored.items()})
    )
    sources = {  # depth of the room and the performer at one fixed instant
        s: SimSource(PERFORMER, POSES[s], seed=i, wall_clock_ns=lambda: round(START_S * 1e9))
        for i, s in enumerate(POSES)
    }
    agents = FakeAgents(lambda s: sources[s].depth_cloud({"max_points": 20000}))
    run = await finished(rig.service(agents).start(RunSpec("icp", "cam-a", rig.sensors)))
    assert run.state == RunState.DONE, run.error
    assert run.floor is not None and run.floor["source"] == "depth"
    truth = invert(POSES["cam-a"]) @ POSES["cam-b"]
    before = pose_error(invert(POSES["cam-a"]) @ off, truth)[1]
    after = pose_error(relative(run.results, "cam-a", "cam-b"), truth)[1]
    assert before == pytest.approx(40.0) and after < 30.0
    assert run.results["cam-b"].metrics["icp_applied"] is True
    assert run.results["cam-b"].method == "previous (stored)+icp"


async def test_points_run_is_solved_at_once_and_committed_once(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    service = rig.service()
    world = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [-0.5, 1.8, 0.3], [0.4, 0.9, -1.0]])
    pairs = PointPairs("cam-b", apply(invert(POSES["cam-b"]), world), world)
    run = service.start(RunSpec("points", "world", ("cam-b",), points=(pairs,)))
    assert run.state == RunState.DONE and run.created_unix_s == START_S
    assert run.results["cam-b"].residual_mm == pytest.approx(0.0, abs=1e-3)
    with pytest.raises(NotFound):
        await service.commit("nope")
    calibration = await service.commit(run.run_id)
    assert rig.hub.calibration is calibration and calibration.version == 1
    np.testing.assert_allclose(rig.hub.pose_of("cam-b")[0], POSES["cam-b"], atol=1e-9)
    with pytest.raises(Conflict, match="already committed as version 1"):
        await service.commit(run.run_id)


@pytest.mark.parametrize(
    ("spec", "error", "message"),
    [
        (RunSpec("bogus", "cam-a", ("cam-a", "cam-b")), InvalidRequest, "method must be"),
        (RunSpec("auto", "cam-a", ("cam-a", "cam-x")), SensorUnavailable, "unknown sensor"),
        (RunSpec("points", "world", ("cam-a",)), InvalidRequest, "at least 3 pairs"),
        (RunSpec("skeleton", "cam-a", ("cam-a",)), Conflict, "at least 2 connected"),
        (RunSpec("icp", "cam-b", ("cam-a",)), InvalidRequest, "reference must be one"),
        (RunSpec("icp", "cam-a", ("cam-a", "cam-b")), Conflict, "have none"),
    ],
)
def test_unusable_specs_are_refused_with_what_to_do(
    tmp_path: Path, spec: RunSpec, error: type[Exception], message: str
) -> None:
    with pytest.raises(error, match=message):
        Rig(tmp_path).service().start(spec)


async def test_one_run_at_a_time_and_offline_sensors_refused(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    service = rig.service()
    run = service.start(RunSpec("skeleton", "cam-a", rig.sensors, duration_s=3.0))
    with pytest.raises(Conflict, match=f"run {run.run_id} is still capturing"):
        service.start(RunSpec("skeleton", "cam-a", rig.sensors))
    with pytest.raises(Conflict, match="is still capturing"):
        await service.commit(run.run_id)
    await finished(run)
    rig.clock.hooks.clear()  # the agents stop streaming
    rig.clock.mono += 10.0
    rig.hub.check_liveness(rig.clock.mono)
    with pytest.raises(Conflict, match="offline"):
        service.start(RunSpec("skeleton", "cam-a", rig.sensors))


async def test_a_sensor_silent_during_the_capture_fails_the_run_by_name(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    rig.silent.add("cam-b")  # its agent stalls: only the frames from before the run exist
    run = await finished(rig.service().start(RunSpec("skeleton", "cam-a", rig.sensors, 3.0)))
    assert run.state == RunState.FAILED
    assert run.error is not None and run.error.startswith("skeleton calibration failed for cam-b")
    assert "need 30 common instants" in run.error


@pytest.mark.parametrize("method", ["auto", "icp"])
async def test_without_open3d_auto_keeps_the_skeleton_poses_and_icp_says_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, method: str
) -> None:
    """A server whose open3d cannot load (a missing system library) still calibrates by
    skeleton; an ICP-only run fails with what to install."""
    import skelfuse.server.calibration_runs as runs
    from skelfuse.calibration.errors import IcpUnavailable

    def no_open3d(*_: object, **__: object) -> None:
        raise IcpUnavailable("open3d does not load: libusb-1.0.so.0 missing")

    monkeypatch.setattr(runs, "refine_with_depth", no_open3d)
    rig = Rig(tmp_path)
    if method == "icp":
        stored = {s: SensorCalibration(pose, "points") for s, pose in POSES.items()}
        rig.hub.use_calibration(rig.store.save(stored))
    cloud = encode_reply(np.random.default_rng(0).uniform(-2, 2, (600, 3)))
    agents = FakeAgents(lambda _: cloud)
    run = await finished(rig.service(agents).start(RunSpec(method, "cam-a", rig.sensors, 3.0)))
    if method == "auto":
        assert run.state == RunState.DONE, run.error
        assert any("no ICP refinement: open3d does not load" in w for w in run.warnings)
        assert {r.method for r in run.results.values()} == {"reference", "skeleton"}
    else:
        assert run.state == RunState.FAILED and run.error is not None
        assert "libusb-1.0.so.0" in run.error


def bumped(pose: Matrix4, yaw_deg: float, shift_m: float) -> Matrix4:
    """``pose`` turned by ``yaw_deg`` about its own +Y and shifted ``shift_m`` along its +X."""
    yaw = np.radians(yaw_deg)
    delta = np.eye(4)
    delta[:3, :3] = axis_rotation("y", yaw)
    delta[0, 3] = shift_m
    result: Matrix4 = pose @ delta
    return result


async def test_sensor_run_solves_a_moved_sensor_back_and_keeps_the_others(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    committed = {"cam-a": POSES["cam-a"], "cam-b": bumped(POSES["cam-b"], 3.0, 0.05)}
    rig.hub.use_calibration(
        rig.store.save({s: SensorCalibration(p, "points") for s, p in committed.items()})
    )
    service = rig.service()
    run = await finished(service.start(RunSpec("sensor", "cam-b", ("cam-b",), duration_s=4.0)))
    assert run.state == RunState.DONE, run.error
    assert set(run.results) == {"cam-b"}  # cam-a is not touched
    result = run.results["cam-b"]
    rotation_deg, translation_mm = pose_error(result.T_world_from_sensor, POSES["cam-b"])
    assert rotation_deg < 0.3 and translation_mm < 15.0
    assert result.method == "sensor" and result.metrics["against"] == "cam-a"
    assert result.metrics["moved_deg"] == pytest.approx(3.0, abs=0.3)
    assert any(w.startswith("no ICP refinement") for w in run.warnings)
    calibration = await service.commit(run.run_id)
    assert np.array_equal(calibration.sensors["cam-a"].T_world_from_sensor, POSES["cam-a"])


async def test_sensor_run_refines_with_icp_against_the_others_clouds(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    committed = {"cam-a": POSES["cam-a"], "cam-b": bumped(POSES["cam-b"], 2.0, 0.03)}
    rig.hub.use_calibration(
        rig.store.save({s: SensorCalibration(p, "points") for s, p in committed.items()})
    )
    sources = {
        s: SimSource(PERFORMER, POSES[s], seed=i, wall_clock_ns=lambda: round(START_S * 1e9))
        for i, s in enumerate(POSES)
    }
    agents = FakeAgents(lambda s: sources[s].depth_cloud({"max_points": 20000}))
    run = await finished(
        rig.service(agents).start(RunSpec("sensor", "cam-b", ("cam-b",), duration_s=4.0))
    )
    assert run.state == RunState.DONE, run.error
    result = run.results["cam-b"]
    # The rig's skeletons are exact, so ICP finds the skeleton pose already right (not applied);
    # it ran against cam-a's cloud placed with cam-a's pose, and agrees.
    assert not run.warnings and "icp_applied" in result.metrics
    assert result.metrics["fitness"] > 0.5 and result.metrics["correction_mm"] < 15.0
    assert pose_error(result.T_world_from_sensor, POSES["cam-b"])[1] < 15.0
    assert sorted(a[0] for a in agents.asked) == ["cam-a", "cam-b"]


async def test_sensor_run_needs_one_sensor_and_another_with_a_pose(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    service = rig.service()
    with pytest.raises(InvalidRequest, match="one sensor"):
        service.start(RunSpec("sensor", "cam-a", ("cam-a", "cam-b")))
    with pytest.raises(Conflict, match="at least one other connected sensor with a pose"):
        service.start(RunSpec("sensor", "cam-b", ("cam-b",)))  # nobody has a pose yet


class CrashingSolvers(ThreadSolvers):
    """Solves in a thread, except ICP, whose worker process dies."""

    async def run(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
        if fn.__name__ == "refine_with_depth":
            raise SolverCrashed("the calibration worker process died while running it")
        return await super().run(fn, *args, **kwargs)


async def test_a_dead_solver_worker_fails_the_run_even_where_icp_is_optional(
    tmp_path: Path,
) -> None:
    rig = Rig(tmp_path)
    cloud = encode_reply(np.random.default_rng(0).uniform(-2, 2, (600, 3)))
    service = CalibrationService(
        rig.hub, rig.store, FakeAgents(lambda _: cloud), rig.clock, solvers=CrashingSolvers()
    )
    run = await finished(service.start(RunSpec("auto", "cam-a", rig.sensors, 3.0)))
    assert run.state == RunState.FAILED and not run.warnings  # not "no ICP refinement"
    assert run.error == "the calibration worker process died while running it"
