"""Calibration runs: capture, solve, review, commit (driven by ``server/routes_calibration.py``).

A run moves through ``capturing → solving → done`` (or ``failed``); only one runs at a time.
Capturing runs on the event loop (sampling the hub's frame buffers, asking agents for depth);
the math (:mod:`skelfuse.calibration.solvers`) runs in a worker process
(:mod:`skelfuse.server.solver_pool`): open3d's ICP keeps the GIL for seconds, and in a thread
it stopped fusion, the API and the agents' heartbeats while it ran. A finished run changes
nothing until it is committed: its poses then become a new stored calibration version, used by
fusion from the next frame.

Methods (docs/calibration.md): ``points`` (≥ 3 corresponding points per sensor → Kabsch);
``skeleton`` (a person walks; bodies seen at common instants → relative poses, levelled with the
reference's floor plane); ``icp`` (depth clouds from every agent, ICP from the current poses,
floor fitted in the reference's cloud); ``auto`` (default: skeleton → icp → floor, keeping the
skeleton poses with a warning when a sensor has no depth or open3d cannot load); ``sensor``
(one sensor, e.g. a bumped one, re-solved against the others, whose poses stay: skeletons, then
ICP against their clouds where depth is available).

Time comes from an injected :class:`~skelfuse.server.clock.Clock` (capture pacing, sample
instants, run stamps), so tests drive a whole run with a fake clock.
"""

from __future__ import annotations

import asyncio
import logging
import uuid
from dataclasses import replace
from typing import Any

import numpy as np

from skelfuse.calibration.errors import CalibrationError, IcpUnavailable
from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.sensor_repair import refine_sensor_with_depth, solve_sensor
from skelfuse.calibration.solvers import (
    Samples,
    SensorResult,
    refine_with_depth,
    solve_points,
    solve_skeletons,
)
from skelfuse.calibration.store import Calibration, CalibrationStore, SensorCalibration, merge
from skelfuse.fusion.spaces import split_by_space
from skelfuse.protocol.transform import Matrix4
from skelfuse.server import calibration_run_progress as stages
from skelfuse.server.calibration_run import CalibrationRun, RunSpec, RunState
from skelfuse.server.calibration_run_capture import (
    capture_skeletons,
    reference_floor_plane,
    sensor_types,
)
from skelfuse.server.calibration_run_checks import validate
from skelfuse.server.calibration_run_progress import RunProgress, StageRates
from skelfuse.server.clock import Clock, SystemClock
from skelfuse.server.depth_clouds import AgentCaller, capture_clouds
from skelfuse.server.errors import (
    AgentRequestFailed,
    Conflict,
    InvalidRequest,
    NotFound,
    ServerError,
    SolverCrashed,
)
from skelfuse.server.hub import FusionHub
from skelfuse.server.solver_pool import ProcessSolvers, Solvers

logger = logging.getLogger(__name__)


class CalibrationService:
    """Owns the runs and applies committed results to the hub and the store."""

    def __init__(
        self,
        hub: FusionHub,
        store: CalibrationStore,
        agents: AgentCaller,
        clock: Clock | None = None,
        keep_runs: int = 20,
        solvers: Solvers | None = None,
    ) -> None:
        """``solvers``: where the math runs (default a worker process; tests with fakes pass
        :class:`~skelfuse.server.solver_pool.ThreadSolvers`)."""
        self.hub = hub
        self.store = store
        self.runs: dict[str, CalibrationRun] = {}
        self._agents = agents
        self._clock = clock or SystemClock()
        self._keep_runs = keep_runs
        self._solvers = solvers or ProcessSolvers()
        self._tasks: set[asyncio.Task[None]] = set()
        self._rates = StageRates()  # how long each stage took here last time (time left)
        self._solver_ready = False  # a solve has returned: the worker process is up
        self._store_lock = asyncio.Lock()  # one store write at a time (each awaits a thread)

    # --- starting ---------------------------------------------------------------------------

    def start(self, spec: RunSpec) -> CalibrationRun:
        """Validate ``spec`` and start the run in the background (``points`` solves at once).

        Raises:
            Conflict: another run is active, a sensor is offline or has no starting pose, or
                too few sensors are connected for the method.
            SensorUnavailable: a sensor (or the reference) is unknown: never connected.
            InvalidRequest: an unknown method, or unusable points.
        """
        busy = self.active_run()
        if busy is not None:
            raise Conflict(f"run {busy.run_id} is still {busy.state}; wait for it to finish")
        validate(spec, self.hub)
        run = CalibrationRun(uuid.uuid4().hex[:12], spec, self._clock.time(), self._tracker(spec))
        if spec.method == "points":
            # Closed form and instant: solve now, so bad points are a 400, not a failed run.
            run.tracker.enter(stages.POINTS)
            try:
                run.results = self._solve_points(spec)
            except CalibrationError as exc:
                raise InvalidRequest(str(exc)) from exc
            self._finish(run)
        else:
            run.tracker.enter(run.tracker.stages[0])  # its first stage from the first answer
            self._solvers.warm()  # the worker starts and imports while the capture runs
            task = asyncio.create_task(self._execute(run), name=f"calibration-{run.run_id}")
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        self.runs[run.run_id] = run
        while len(self.runs) > self._keep_runs:
            oldest = min(self.runs.values(), key=lambda r: r.created_unix_s)
            if oldest.active:
                break
            del self.runs[oldest.run_id]
        return run

    async def close(self) -> None:
        """Cancel the active run and stop the solver worker (with the server)."""
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self._solvers.aclose()

    def _tracker(self, spec: RunSpec) -> RunProgress:
        """The run's stages, with the work units of each (for the progress split and time left).

        A unit is a second of the walk, a sensor paired (skeleton solve), one capture of every
        sensor's depth, one sensor refined by ICP (two passes of every non-reference sensor;
        method ``sensor``: the one sensor once)."""
        others = max(1, len(spec.sensors) - 1)
        if spec.method == "sensor":
            others = max(1, len(self.hub.connected_poses()) - 1)
        units = {
            stages.WALK: spec.duration_s,
            stages.SKELETONS: others,
            stages.DEPTH: 1,
            stages.ICP: 1 if spec.method == "sensor" else 2 * others,
            stages.POINTS: 1,
        }
        return RunProgress(stages.STAGES[spec.method], units, self._rates, self._clock)

    def active_run(self) -> CalibrationRun | None:
        return next((r for r in self.runs.values() if r.active), None)

    def viewer_pose(self, sensor_id: str) -> tuple[Matrix4 | None, str]:
        """The pose viewers place the sensor's cloud and bodies with: a running calibration's
        provisional pose once it has one (so people see whether the clouds line up), else what
        fusion uses (:meth:`FusionHub.pose_of`)."""
        run = self.active_run()
        if run is not None and sensor_id in run.provisional:
            return run.provisional[sensor_id], "provisional"
        return self.hub.pose_of(sensor_id)

    def run(self, run_id: str) -> CalibrationRun:
        """The run with this id.

        Raises:
            NotFound: no such run (never started, or forgotten after ``keep_runs`` newer ones).
        """
        run = self.runs.get(run_id)
        if run is None:
            raise NotFound(f"no calibration run {run_id!r}")
        return run

    # --- running ----------------------------------------------------------------------------

    async def _execute(self, run: CalibrationRun) -> None:
        spec = run.spec
        try:
            if spec.method == "sensor":
                run.results = await self._resolve_sensor(run, spec.sensors[0])
                self._finish(run)
                return
            poses: dict[str, SensorResult] = {}
            if spec.method in ("skeleton", "auto"):
                samples = await self._capture(run, spec.sensors)
                run.state = RunState.SOLVING
                run.tracker.enter(stages.SKELETONS, measure=self._solver_ready)
                floor_plane = reference_floor_plane(self.hub, spec.reference)
                types = sensor_types(self.hub, spec.sensors)  # rgb pairs: their RANSAC settings
                solution = await self._solvers.run(
                    solve_skeletons, spec.reference, spec.sensors, samples, floor_plane, types
                )
                self._solver_ready = True
                poses, run.floor = solution.results, solution.floor
                run.warnings.extend(solution.warnings)
                run.provisional = {s: r.T_world_from_sensor for s, r in poses.items()}
            if spec.method in ("icp", "auto"):
                poses = await self._refine(run, spec, poses)
            run.results = poses
            self._finish(run)
        except (CalibrationError, ServerError) as exc:
            if isinstance(exc, SolverCrashed):  # the next run starts a new worker: not timed
                self._solver_ready = False
            self._fail(run, str(exc))
        except Exception as exc:  # never leave a run hanging in "capturing"
            logger.exception("calibration run %s failed", run.run_id)
            self._fail(run, f"internal error: {type(exc).__name__}: {exc}")

    async def _refine(
        self, run: CalibrationRun, spec: RunSpec, poses: dict[str, SensorResult]
    ) -> dict[str, SensorResult]:
        """ICP on depth clouds from ``poses`` (or the current ones); ``auto`` keeps ``poses`` when
        a sensor has no depth (e.g. a replayed recording) or open3d cannot load here."""
        run.state = RunState.CAPTURING
        run.tracker.enter(stages.DEPTH)
        try:
            clouds = await capture_clouds(self._agents, spec.sensors, self.hub.sensors)
            run.state = RunState.SOLVING
            run.tracker.enter(stages.ICP, measure=self._solver_ready)
            start = poses or {s: self._current(s) for s in spec.sensors}
            refined = await self._solvers.run_reporting(
                refine_with_depth,
                run.tracker.advance,
                spec.reference,
                clouds,
                start,
                spec.min_overlap,
            )
        except (AgentRequestFailed, IcpUnavailable) as exc:
            if spec.method == "icp":
                raise
            run.warnings.append(f"no ICP refinement: {exc}; kept the skeleton poses")
            return poses
        self._solver_ready = True
        if refined.floor is not None:  # else the skeleton step's floor stands
            run.floor = refined.floor
        run.warnings.extend(refined.warnings)
        return refined.results

    async def _resolve_sensor(self, run: CalibrationRun, sensor_id: str) -> dict[str, SensorResult]:
        """Method ``sensor``: ``sensor_id`` against the other connected, posed sensors, whose
        poses stay; skeletons, then ICP where every one of them has depth (else a warning)."""
        fixed = {s: p for s, p in self.hub.connected_poses().items() if s != sensor_id}
        committed = self._current(sensor_id).T_world_from_sensor
        sensors = (sensor_id, *sorted(fixed))
        samples = await self._capture(run, sensors)
        run.state = RunState.SOLVING
        others = ", ".join(sorted(fixed))
        run.tracker.enter(stages.SKELETONS, f"{sensor_id} against {others}", self._solver_ready)
        types = sensor_types(self.hub, sensors)
        result = await self._solvers.run(solve_sensor, sensor_id, fixed, samples, types)
        self._solver_ready = True
        run.provisional = {sensor_id: result.T_world_from_sensor}
        run.state = RunState.CAPTURING
        run.tracker.enter(stages.DEPTH)
        try:
            clouds = await capture_clouds(self._agents, sensors, self.hub.sensors)
            run.state = RunState.SOLVING
            run.tracker.enter(stages.ICP)  # the worker has just solved the skeletons
            result = await self._solvers.run_reporting(
                refine_sensor_with_depth,
                run.tracker.advance,
                sensor_id,
                clouds,
                result,
                fixed,
                run.spec.min_overlap,
            )
        except (AgentRequestFailed, CalibrationError) as exc:
            run.warnings.append(f"no ICP refinement: {exc}; kept the skeleton pose")
        moved_deg, moved_mm = pose_error(result.T_world_from_sensor, committed)
        metrics = {
            **result.metrics,
            "moved_deg": round(moved_deg, 3),
            "moved_mm": round(moved_mm, 1),
        }
        return {sensor_id: replace(result, metrics=metrics)}

    def _finish(self, run: CalibrationRun) -> None:
        run.state = RunState.DONE
        run.tracker.finish()
        run.provisional = {}
        run.finished_unix_s = self._clock.time()
        logger.info(
            "calibration run %s done: %s",
            run.run_id,
            {k: v.residual_mm for k, v in run.results.items()},
        )

    def _fail(self, run: CalibrationRun, message: str) -> None:
        run.state, run.error = RunState.FAILED, message
        run.tracker.fail()
        run.provisional = {}
        run.finished_unix_s = self._clock.time()
        logger.warning("calibration run %s failed: %s", run.run_id, message)

    def _current(self, sensor_id: str) -> SensorResult:
        pose, state = self.hub.pose_of(sensor_id)
        if pose is None:  # _validate refuses icp runs on sensors without a pose
            raise Conflict(f"sensor {sensor_id!r} has no pose to refine")
        return SensorResult(pose.copy(), f"previous ({state})", None)

    # --- capture ----------------------------------------------------------------------------

    async def _capture(self, run: CalibrationRun, sensors: tuple[str, ...]) -> Samples:
        """The walk stage: every sensor's bodies for the run's ``duration_s``."""
        duration = run.spec.duration_s
        run.tracker.enter(stages.WALK, f"{duration:.0f} s left")
        return await capture_skeletons(self.hub, self._clock, sensors, duration, run.tracker)

    def _solve_points(self, spec: RunSpec) -> dict[str, SensorResult]:
        if spec.reference == "world":
            return solve_points(spec.points, None, np.eye(4))
        current: Matrix4 | None = self.hub.pose_of(spec.reference)[0]
        return solve_points(spec.points, spec.reference, np.eye(4) if current is None else current)

    # --- commit and history -------------------------------------------------------------------

    async def commit(self, run_id: str) -> Calibration:
        """Store the run's poses as a new calibration version and fuse with it from now on.

        The files are written and fsync'ed in a thread (tens of ms on a busy disk, 42 ms median
        on the 2-core test machine: over the event loop's 20 ms budget); the hub switches to the
        new version on the loop.

        Raises:
            NotFound: no such run.
            Conflict: the run is not done, or was committed already.
        """
        async with self._store_lock:  # a second commit of the same run waits, then is refused
            return await self._commit(self.run(run_id))

    async def _commit(self, run: CalibrationRun) -> Calibration:
        run_id = run.run_id
        if run.state != RunState.DONE:
            hint = (
                f"it is still {run.state} ({run.progress:.0%}); wait until its state is done"
                if run.active
                else f"it failed: {run.error}"
            )
            raise Conflict(f"run {run_id} cannot be committed: {hint}")
        if run.committed_version is not None:
            raise Conflict(f"run {run_id} was already committed as version {run.committed_version}")
        updates = {
            sensor_id: SensorCalibration(
                r.T_world_from_sensor, r.method, r.residual_mm, {"run": run_id, **r.metrics}
            )
            for sensor_id, r in run.results.items()
        }
        note = f"run {run_id} ({run.spec.method})"
        fixed, spaces = split_by_space(self.hub.sensors, updates)  # a moving sensor: its space

        def save() -> Calibration:
            current = self.store.load()
            kept = current.spaces if current else {}
            return self.store.save(merge(current, fixed), note=note, spaces={**kept, **spaces})

        calibration = await asyncio.to_thread(save)
        self.hub.use_calibration(calibration)
        run.committed_version = calibration.version
        return calibration

    async def history(self) -> list[Calibration]:
        """Every stored version, oldest first (read in a thread: one file per version)."""
        return await asyncio.to_thread(self.store.history)

    async def rollback(self, version: int) -> Calibration:
        """Make stored ``version`` active again (saved as a new version).

        Raises:
            UnknownVersion: no such version.
        """
        async with self._store_lock:
            calibration = await asyncio.to_thread(self.store.rollback, version)
            self.hub.use_calibration(calibration)
        return calibration

    async def import_json(self, data: Any) -> Calibration:
        """Validate an exported calibration and make it active (a new version).

        Raises:
            CalibrationFileError: not a valid calibration export.
        """
        async with self._store_lock:
            calibration = await asyncio.to_thread(self.store.import_json, data)
            self.hub.use_calibration(calibration)
        return calibration
