"""Calibration runs: capture, solve, review, commit (driven by ``server/routes_calibration.py``).

A run moves through ``capturing → solving → done`` (or ``failed``); only one runs at a time.
Capturing happens on the event loop (sampling the hub's frame buffers, asking agents for depth
clouds); the math runs in a worker thread so fusion and the API stay responsive. A finished run
changes nothing until it is committed: then its poses become a new stored calibration version
and fusion uses them from the next frame.

Methods (docs/calibration.md):
- ``points``: ≥ 3 corresponding points per sensor → Kabsch, with residuals;
- ``skeleton``: a person walks; midline joints seen by the reference and each other sensor at
  the same instants → robust relative poses; world levelled with the reference's floor plane;
- ``icp``: depth point clouds from every agent, point-to-plane ICP from the current poses,
  then the floor fitted in the reference's cloud;
- ``auto`` (default): skeleton → icp → floor.
"""

from __future__ import annotations

import asyncio
import logging
import time
import uuid
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import CalibrationError, NotEnoughCorrespondences
from skelfuse.calibration.floor import FloorFit, fit_floor, floor_from_kinect_plane, level_to_floor
from skelfuse.calibration.icp import refine_all
from skelfuse.calibration.rigid import fit_rigid, pose_error
from skelfuse.calibration.skeleton_pose import (
    SKELETON_ERROR_BOUND,
    SkeletonFit,
    solve_from_skeletons,
)
from skelfuse.calibration.store import Calibration, CalibrationStore, SensorCalibration, merge
from skelfuse.fusion.hub import AgentRequestFailed, FusionHub, SensorUnavailable
from skelfuse.fusion.sensors import bodies_at
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import Matrix4, invert
from skelfuse.protocol.wire import Body

logger = logging.getLogger(__name__)

METHODS = ("auto", "skeleton", "points", "icp")
SAMPLE_HZ = 30.0
SAMPLE_DELAY_S = 0.15
"""Sample a little in the past so every sensor's frames around the instant have arrived."""
DEPTH_TIMEOUT_S = 20.0


class CalibrationRequestError(Exception):
    """A request the API must refuse: ``status`` is the HTTP code, the message says what to do."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


class RunState(StrEnum):
    CAPTURING = "capturing"
    SOLVING = "solving"
    DONE = "done"
    FAILED = "failed"


@dataclass(frozen=True, slots=True)
class PointPairs:
    """Corresponding points: ``sensor_points`` in the sensor's frame, ``reference_points`` in
    the reference sensor's frame or the world (both (N, 3), metres)."""

    sensor: str
    sensor_points: npt.NDArray[np.float64]
    reference_points: npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class RunSpec:
    method: str
    reference: str
    """A sensor id, or ``world`` (points method only: reference points are world coordinates)."""
    sensors: tuple[str, ...]
    duration_s: float = 15.0
    points: tuple[PointPairs, ...] = ()
    min_overlap: float = 0.3


@dataclass(slots=True)
class SensorResult:
    T_world_from_sensor: Matrix4
    method: str
    residual_mm: float | None
    warnings: list[str] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "T_world_from_sensor": np.round(self.T_world_from_sensor, 9).tolist(),
            "method": self.method,
            "residual_mm": None if self.residual_mm is None else round(self.residual_mm, 2),
            "warnings": self.warnings,
            "metrics": self.metrics,
        }


@dataclass(slots=True)
class CalibrationRun:
    run_id: str
    spec: RunSpec
    created_unix_s: float
    state: RunState = RunState.CAPTURING
    stage: str = "starting"
    progress: float = 0.0
    finished_unix_s: float | None = None
    results: dict[str, SensorResult] = field(default_factory=dict)
    floor: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)
    error: str | None = None
    committed_version: int | None = None

    @property
    def active(self) -> bool:
        return self.state in (RunState.CAPTURING, RunState.SOLVING)

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.run_id,
            "method": self.spec.method,
            "reference": self.spec.reference,
            "sensors": list(self.spec.sensors),
            "state": str(self.state),
            "stage": self.stage,
            "progress": round(self.progress, 3),
            "created_unix_s": self.created_unix_s,
            "finished_unix_s": self.finished_unix_s,
            "results": {k: v.to_json() for k, v in sorted(self.results.items())},
            "floor": self.floor,
            "warnings": self.warnings,
            "error": self.error,
            "committed_version": self.committed_version,
        }


class CalibrationService:
    """Owns the runs and applies committed results to the hub and the store."""

    def __init__(self, hub: FusionHub, store: CalibrationStore, keep_runs: int = 20) -> None:
        self.hub = hub
        self.store = store
        self.runs: dict[str, CalibrationRun] = {}
        self._keep_runs = keep_runs
        self._tasks: set[asyncio.Task[None]] = set()

    # --- starting ---------------------------------------------------------------------------

    def start(self, spec: RunSpec) -> CalibrationRun:
        """Validate ``spec`` and start the run in the background.

        Raises:
            CalibrationRequestError: 409 while another run is active or a sensor is offline or
                has no starting pose; 400 for unknown sensors or unusable points.
        """
        busy = next((r for r in self.runs.values() if r.active), None)
        if busy is not None:
            raise CalibrationRequestError(
                409, f"run {busy.run_id} is still {busy.state}; wait for it to finish"
            )
        self._validate(spec)
        run = CalibrationRun(uuid.uuid4().hex[:12], spec, time.time())
        if spec.method == "points":
            # Closed form and instant: solve now, so bad points are a 400, not a failed run.
            try:
                run.results = self._solve_points(spec)
            except CalibrationError as exc:
                raise CalibrationRequestError(400, str(exc)) from exc
            self._finish(run)
        else:
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

    def _validate(self, spec: RunSpec) -> None:
        if spec.method not in METHODS:
            raise CalibrationRequestError(400, f"method must be one of {', '.join(METHODS)}")
        known = self.hub.sensors
        unknown = [s for s in spec.sensors if s not in known]
        if spec.reference != "world" and spec.reference not in known:
            unknown.append(spec.reference)
        if unknown:
            raise CalibrationRequestError(
                400, f"unknown sensor(s) {sorted(set(unknown))}; known: {sorted(known) or 'none'}"
            )
        if spec.method == "points":
            if not spec.points:
                raise CalibrationRequestError(
                    400, "method points needs 'points': at least 3 pairs per sensor"
                )
            return
        offline = [s for s in spec.sensors if not known[s].connected]
        if offline:
            raise CalibrationRequestError(
                409, f"sensor(s) {offline} are offline; start their agents and retry"
            )
        if len(spec.sensors) < 2 and spec.method in ("skeleton", "auto"):
            raise CalibrationRequestError(
                409, f"method {spec.method} needs at least 2 connected sensors"
            )
        if spec.reference not in spec.sensors:
            raise CalibrationRequestError(400, "the reference must be one of the run's sensors")
        if spec.method == "icp":
            missing = [s for s in spec.sensors if self.hub.pose_of(s)[0] is None]
            if missing:
                raise CalibrationRequestError(
                    409,
                    f"icp refines existing poses, but {missing} have none: run 'skeleton', "
                    "'points' or 'auto' first",
                )

    # --- running ----------------------------------------------------------------------------

    async def _execute(self, run: CalibrationRun) -> None:
        spec = run.spec
        try:
            poses: dict[str, SensorResult] = {}
            if spec.method in ("skeleton", "auto"):
                share = 0.7 if spec.method == "auto" else 0.95
                samples = await self._capture_skeletons(run, 0.0, share)
                run.state, run.stage = RunState.SOLVING, "solving skeleton poses"
                poses = await asyncio.to_thread(self._solve_skeletons, spec, samples, run)
                run.progress = share
            if spec.method in ("icp", "auto"):
                run.state, run.stage = RunState.CAPTURING, "capturing depth clouds"
                try:
                    clouds = await self._capture_clouds(spec)
                except AgentRequestFailed as exc:
                    if spec.method == "icp":
                        raise
                    # auto degrades to the skeleton result rather than failing outright (a
                    # source without depth, e.g. a replayed recording).
                    run.warnings.append(f"no ICP refinement: {exc}; kept the skeleton poses")
                    clouds = None
                if clouds is not None:
                    run.state, run.stage = RunState.SOLVING, "refining with ICP"
                    if not poses:
                        poses = {s: self._current(s) for s in spec.sensors}
                    poses = await asyncio.to_thread(self._solve_icp, spec, clouds, poses, run)
            run.results = poses
            self._finish(run)
        except (CalibrationError, AgentRequestFailed, SensorUnavailable) as exc:
            self._fail(run, str(exc))
        except Exception as exc:  # never leave a run hanging in "capturing"
            logger.exception("calibration run %s failed", run.run_id)
            self._fail(run, f"internal error: {type(exc).__name__}: {exc}")

    def _finish(self, run: CalibrationRun) -> None:
        run.state, run.stage, run.progress = RunState.DONE, "done", 1.0
        run.finished_unix_s = time.time()
        logger.info(
            "calibration run %s done: %s",
            run.run_id,
            {k: v.residual_mm for k, v in run.results.items()},
        )

    def _fail(self, run: CalibrationRun, message: str) -> None:
        run.state, run.stage, run.error = RunState.FAILED, "failed", message
        run.finished_unix_s = time.time()
        logger.warning("calibration run %s failed: %s", run.run_id, message)

    def _current(self, sensor_id: str) -> SensorResult:
        pose, state = self.hub.pose_of(sensor_id)
        assert pose is not None  # validated at start
        return SensorResult(pose.copy(), f"previous ({state})", None)

    # --- skeleton --------------------------------------------------------------------------

    async def _capture_skeletons(
        self, run: CalibrationRun, start: float, share: float
    ) -> dict[str, list[tuple[Body, ...]]]:
        """Every sensor's bodies at common instants (30 per second) for ``duration_s``."""
        spec = run.spec
        run.stage = f"walk through the capture area ({spec.duration_s:.0f} s)"
        samples: dict[str, list[tuple[Body, ...]]] = {s: [] for s in spec.sensors}
        began = time.monotonic()
        gap = self.hub.settings.interpolation_gap_s
        while (elapsed := time.monotonic() - began) < spec.duration_s:
            run.progress = start + share * elapsed / spec.duration_s
            t = time.time() - SAMPLE_DELAY_S
            for sensor_id in spec.sensors:
                sensor = self.hub.sensors.get(sensor_id)
                bodies = None
                if sensor is not None and sensor.connected:
                    bodies = bodies_at(sensor.frames, t, gap, 1.5 / max(sensor.nominal_fps, 1))
                samples[sensor_id].append(bodies or ())
            await asyncio.sleep(1.0 / SAMPLE_HZ)
        return samples

    def _solve_skeletons(
        self, spec: RunSpec, samples: dict[str, list[tuple[Body, ...]]], run: CalibrationRun
    ) -> dict[str, SensorResult]:
        ref_samples = samples[spec.reference]
        T_ref_from: dict[str, Matrix4] = {spec.reference: np.eye(4)}
        results: dict[str, SensorResult] = {}
        failures: list[str] = []
        for sensor_id in spec.sensors:
            if sensor_id == spec.reference:
                continue
            try:
                fit, note = solve_with_body_pairing(ref_samples, samples[sensor_id])
            except CalibrationError as exc:
                failures.append(f"{sensor_id}: {exc}")
                continue
            T_ref_from[sensor_id] = fit.T_ref_from_other
            warnings = [*fit.warnings, *([note] if note else [])]
            results[sensor_id] = SensorResult(
                fit.T_ref_from_other,
                "skeleton",
                fit.residual_mm,
                warnings,
                {
                    "trust": fit.trust,
                    "frames_used": fit.frames_used,
                    "joints_used": fit.joints_used,
                    "inlier_ratio": round(fit.inlier_ratio, 3),
                    "spread_m": round(fit.spread_m, 3),
                },
            )
        if failures:
            raise NotEnoughCorrespondences("skeleton calibration failed for " + "; ".join(failures))
        # The world: the reference's floor plane, origin under the centre of the walked path.
        floor = self._reference_floor_plane(spec.reference)
        pelvis = [b.joints_m[JointId.SPINE_BASE] for bodies in ref_samples for b in bodies]
        pelvis_array = np.asarray(pelvis, dtype=np.float64).reshape(-1, 3)
        finite = pelvis_array[np.isfinite(pelvis_array).all(axis=1)]
        centre = np.median(finite, axis=0) if len(finite) else None
        if floor is None:
            run.warnings.append(
                "the reference sensor reports no floor plane: the world is its camera frame "
                "until an icp or auto run levels it"
            )
            T_world_from_ref = np.eye(4)
            run.floor = {"source": "none"}
        else:
            T_world_from_ref = level_to_floor(np.eye(4), floor, centre_world=centre)
            run.floor = {"source": "kinect_floor_plane", "sensor_height_m": round(floor.d, 4)}
        results[spec.reference] = SensorResult(T_world_from_ref, "reference", 0.0)
        for sensor_id, result in results.items():
            if sensor_id != spec.reference:
                result.T_world_from_sensor = T_world_from_ref @ T_ref_from[sensor_id]
        return results

    def _reference_floor_plane(self, sensor_id: str) -> FloorFit | None:
        sensor = self.hub.sensors.get(sensor_id)
        for timed in reversed(sensor.frames if sensor else ()):
            if timed.frame.floor is not None:
                return floor_from_kinect_plane(*timed.frame.floor)
        return None

    # --- points -----------------------------------------------------------------------------

    def _solve_points(self, spec: RunSpec) -> dict[str, SensorResult]:
        if spec.reference == "world":
            T_world_from_ref: Matrix4 = np.eye(4)
        else:
            current, _ = self.hub.pose_of(spec.reference)
            T_world_from_ref = np.eye(4) if current is None else current
        results: dict[str, SensorResult] = {}
        for entry in spec.points:
            fit = fit_rigid(entry.sensor_points, entry.reference_points)
            results[entry.sensor] = SensorResult(
                T_world_from_ref @ fit.T_dst_from_src,
                "points",
                fit.rmse_m * 1000.0,
                metrics={
                    "pairs": len(entry.sensor_points),
                    "residuals_mm": [round(r * 1000, 2) for r in fit.residuals_m],
                },
            )
        if spec.reference != "world" and spec.reference not in results:
            results[spec.reference] = SensorResult(T_world_from_ref.copy(), "reference", 0.0)
        return results

    # --- icp and floor --------------------------------------------------------------------

    async def _capture_clouds(self, spec: RunSpec) -> dict[str, npt.NDArray[np.float64]]:
        async def one(sensor_id: str) -> tuple[str, npt.NDArray[np.float64]]:
            result = await self.hub.request(
                sensor_id, "depth_cloud", {"max_points": 20000}, DEPTH_TIMEOUT_S
            )
            return sensor_id, decode_cloud(sensor_id, result)

        pairs = await asyncio.gather(*(one(s) for s in spec.sensors))
        return dict(pairs)

    def _solve_icp(
        self,
        spec: RunSpec,
        clouds: dict[str, npt.NDArray[np.float64]],
        initial: dict[str, SensorResult],
        run: CalibrationRun,
    ) -> dict[str, SensorResult]:
        init_poses = {s: initial[s].T_world_from_sensor for s in spec.sensors}
        from_skeleton = any(r.method == "skeleton" for r in initial.values())
        refined = refine_all(
            clouds,
            init_poses,
            spec.reference,
            min_overlap=spec.min_overlap,
            max_correction=SKELETON_ERROR_BOUND if from_skeleton else None,
        )
        results: dict[str, SensorResult] = {}
        for sensor_id in spec.sensors:
            before = initial[sensor_id]
            icp = refined.get(sensor_id)
            if icp is None:  # the reference
                results[sensor_id] = before
                continue
            method = "icp" if icp.applied else before.method
            moved_deg, moved_mm = pose_error(icp.T_target_from_source, before.T_world_from_sensor)
            results[sensor_id] = SensorResult(
                icp.T_target_from_source,
                f"{before.method}+icp" if icp.applied and before.method != "icp" else method,
                icp.inlier_rmse_m * 1000.0,
                [*before.warnings, *icp.warnings],
                {
                    **before.metrics,
                    "icp_applied": icp.applied,
                    "fitness": round(icp.fitness, 4),
                    "overlap": round(icp.overlap, 4),
                    "initial_fitness": round(icp.initial_fitness, 4),
                    "initial_rmse_mm": round(icp.initial_rmse_m * 1000, 2),
                    "correction_deg": round(moved_deg, 3),
                    "correction_mm": round(moved_mm, 1),
                },
            )
        # Floor from depth in the reference's cloud; keep the world's yaw and origin.
        T_world_from_ref = results[spec.reference].T_world_from_sensor
        rotation_ref_from_world = T_world_from_ref[:3, :3].T
        try:
            floor = fit_floor(clouds[spec.reference], up_hint=rotation_ref_from_world[:, 1])
        except CalibrationError as exc:
            run.warnings.append(f"no floor found in the reference's depth ({exc}); not levelled")
            return results
        T_new_from_ref = level_to_floor(
            T_world_from_ref,
            floor,
            centre_world=np.zeros(3),
            forward_ref=rotation_ref_from_world[:, 2],
        )
        T_new_from_old = T_new_from_ref @ invert(T_world_from_ref)
        tilt = float(np.degrees(np.arccos(np.clip(T_new_from_old[1, 1], -1.0, 1.0))))
        run.floor = {
            "source": "depth",
            "sensor_height_m": round(float(floor.d), 4),
            "rmse_mm": round(floor.rmse_m * 1000, 2),
            "inliers": floor.inlier_count,
            "correction_deg": round(tilt, 3),
            "correction_mm": round(float(abs(T_new_from_old[1, 3])) * 1000, 1),
        }
        for result in results.values():
            result.T_world_from_sensor = T_new_from_old @ result.T_world_from_sensor
        return results

    # --- commit and history -------------------------------------------------------------------

    def commit(self, run_id: str) -> Calibration:
        run = self.runs.get(run_id)
        if run is None:
            raise CalibrationRequestError(404, f"no calibration run {run_id!r}")
        if run.state != RunState.DONE:
            hint = (
                f"it is still {run.state} ({run.progress:.0%}); wait until its state is done"
                if run.active
                else f"it failed: {run.error}"
            )
            raise CalibrationRequestError(409, f"run {run_id} cannot be committed: {hint}")
        if run.committed_version is not None:
            raise CalibrationRequestError(
                409, f"run {run_id} was already committed as version {run.committed_version}"
            )
        updates = {
            sensor_id: SensorCalibration(
                r.T_world_from_sensor, r.method, r.residual_mm, {"run": run_id, **r.metrics}
            )
            for sensor_id, r in run.results.items()
        }
        calibration = self.store.save(
            merge(self.store.load(), updates), note=f"run {run_id} ({run.spec.method})"
        )
        self.hub.calibration = calibration
        run.committed_version = calibration.version
        return calibration

    def rollback(self, version: int) -> Calibration:
        calibration = self.store.rollback(version)
        self.hub.calibration = calibration
        return calibration

    def import_json(self, data: Any) -> Calibration:
        calibration = self.store.import_json(data)
        self.hub.calibration = calibration
        return calibration


MIN_PAIR_SAMPLES = 30
AGREE_DEG, AGREE_MM = 5.0, 150.0


def solve_with_body_pairing(
    ref_samples: list[tuple[Body, ...]], other_samples: list[tuple[Body, ...]]
) -> tuple[SkeletonFit, str | None]:
    """Relative pose from two sensors' bodies, not knowing which body is which person.

    Every (reference tracking id, other tracking id) pair seen at the same instants is a
    hypothesis; each is fitted on its own, the best (lowest residual, enough joints) wins, and
    the hypotheses that agree with it (a re-acquired body under a new id is the same person)
    are pooled for the final fit. With one person in the room this is simply all instants.

    Raises:
        NotEnoughCorrespondences / DegenerateGeometry: no hypothesis could be fitted.
    """
    groups: dict[tuple[int, int], list[tuple[Body, Body]]] = {}
    for ref_bodies, other_bodies in zip(ref_samples, other_samples, strict=True):
        if len(ref_bodies) * len(other_bodies) > 9:
            continue  # too crowded to be useful
        for ref_body in ref_bodies:
            for other_body in other_bodies:
                key = (ref_body.tracking_id, other_body.tracking_id)
                groups.setdefault(key, []).append((ref_body, other_body))
    candidates = {k: v for k, v in groups.items() if len(v) >= MIN_PAIR_SAMPLES}
    if not candidates:
        raise NotEnoughCorrespondences(
            "the two sensors never saw the same person for long enough "
            f"(need {MIN_PAIR_SAMPLES} common instants): walk where both can see you"
        )
    fits: dict[tuple[int, int], SkeletonFit] = {}
    errors: list[str] = []
    for key, pairs in candidates.items():
        try:
            fits[key] = _fit_pairs(pairs)
        except CalibrationError as exc:
            errors.append(str(exc))
    if not fits:
        raise NotEnoughCorrespondences(errors[0] if errors else "no usable body pairs")
    best_key = min(fits, key=lambda k: fits[k].residual_mm / np.sqrt(max(fits[k].joints_used, 1)))
    best = fits[best_key]
    agreeing = [k for k, fit in fits.items() if _agrees(fit, best)]
    note = None
    if len(fits) > len(agreeing):
        note = (
            f"{len(fits) - len(agreeing)} body pairing(s) disagreed and were left out "
            "(more than one person in view, or mismatched bodies)"
        )
    if len(agreeing) == 1:
        return best, note
    pooled = [pair for k in agreeing for pair in candidates[k]]
    return _fit_pairs(pooled), note


def _agrees(fit: SkeletonFit, best: SkeletonFit) -> bool:
    rotation_deg, translation_mm = pose_error(fit.T_ref_from_other, best.T_ref_from_other)
    return rotation_deg < AGREE_DEG and translation_mm < AGREE_MM


def _fit_pairs(pairs: list[tuple[Body, Body]]) -> SkeletonFit:
    ref_joints = np.stack([a.joints_m for a, _ in pairs]).astype(np.float64)
    ref_states = np.stack([a.states for a, _ in pairs])
    other_joints = np.stack([b.joints_m for _, b in pairs]).astype(np.float64)
    other_states = np.stack([b.states for _, b in pairs])
    return solve_from_skeletons(
        ref_joints, ref_states, other_joints, other_states, rng=np.random.default_rng(0)
    )


def decode_cloud(sensor_id: str, result: Any) -> npt.NDArray[np.float64]:
    """Validate an agent's ``depth_cloud`` answer: (N, 3) finite float32 points, sensor frame."""
    if not isinstance(result, dict) or not isinstance(result.get("points"), bytes):
        raise AgentRequestFailed(f"sensor {sensor_id!r} sent a depth cloud without points")
    raw = result["points"]
    if len(raw) % 12:
        raise AgentRequestFailed(f"sensor {sensor_id!r}: depth cloud is not N×3 float32")
    points = np.frombuffer(raw, dtype="<f4").reshape(-1, 3).astype(np.float64)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 500:
        raise AgentRequestFailed(
            f"sensor {sensor_id!r} sent only {len(points)} depth points; is its view blocked?"
        )
    return points
