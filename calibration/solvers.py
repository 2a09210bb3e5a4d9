"""The solvers of a calibration run: captured data in, every sensor's ``T_world_from_sensor`` out.

Pure functions (no sockets, no clock); the server's run orchestration
(``skelfuse.server.calibration_runs``) captures the data and calls them in a worker thread.

Frames: each sensor's own frame (metres, +X to the sensor's left, +Y up, +Z forward); the
*reference* sensor's frame, which anchors the world; the world (metres, right-handed, +Y up,
floor at y = 0). Poses are (4, 4) float64 with ``p_world = T_world_from_sensor @ p_sensor``.

- :func:`solve_points`: corresponding points → Kabsch per sensor;
- :func:`solve_skeletons`: bodies at common instants → poses relative to the reference, the
  world levelled with the reference's floor plane (Kinect ``FloorClipPlane``);
- :func:`refine_with_depth`: depth clouds → ICP from the current poses, then the world
  re-levelled with the floor fitted in the reference's cloud;

One sensor (a bumped one) against the others, whose poses stay as they are (drift repair):
:mod:`skelfuse.calibration.sensor_repair`. Pairs with an ``rgb`` (mono) sensor are fitted with
that sensor's looser RANSAC settings (:func:`body_pairing.pairing_thresholds`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.body_pairing import pairing_thresholds, solve_with_body_pairing
from skelfuse.calibration.errors import CalibrationError, NotEnoughCorrespondences
from skelfuse.calibration.floor import fit_floor, floor_from_kinect_plane, level_to_floor
from skelfuse.calibration.icp import IcpResult, Progress, refine_all, scaled_progress
from skelfuse.calibration.rigid import fit_rigid, pose_error
from skelfuse.calibration.skeleton_pose import SKELETON_ERROR_BOUND
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import Matrix4, invert
from skelfuse.protocol.wire import Body

FloatArray = npt.NDArray[np.float64]
Samples = Mapping[str, Sequence[tuple[Body, ...]]]
"""Sensor id → per instant (the same instants for every sensor) the bodies it saw, joints in
its own frame; ``()`` where it saw nobody."""
SensorTypes = Mapping[str, str]
"""Sensor id → its ``sensor_type`` (``kinect_v2``, ``rgb``, ...: the wire's); a sensor left out
is fitted with the depth sensors' settings."""


@dataclass(frozen=True, slots=True)
class PointPairs:
    """Corresponding points: ``sensor_points`` in the sensor's frame, ``reference_points`` in
    the reference sensor's frame or the world (both (N, 3), metres)."""

    sensor: str
    sensor_points: FloatArray
    reference_points: FloatArray


@dataclass(frozen=True, slots=True)
class SensorResult:
    """One sensor's solved pose: (4, 4) ``T_world_from_sensor`` (metres), the method that gave
    it, its RMS residual (mm; None when not measured), warnings for the user and metrics."""

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


@dataclass(frozen=True, slots=True)
class Solution:
    """What a solver found: a pose per sensor, how the world was levelled (the run's ``floor``
    report; None when this step did not level it) and warnings for the whole run."""

    results: dict[str, SensorResult]
    floor: dict[str, Any] | None = None
    warnings: tuple[str, ...] = ()


def solve_points(
    pairs: Sequence[PointPairs], reference: str | None, T_world_from_ref: Matrix4
) -> dict[str, SensorResult]:
    """Each sensor's pose from its corresponding points (weighted Kabsch, ``fit_rigid``).

    Args:
        pairs: per sensor, (N, 3) points in its frame and the same points in the reference's
            frame (or the world when ``reference`` is None), metres.
        reference: the reference sensor's id; None when the reference points are world
            coordinates.
        T_world_from_ref: (4, 4) the reference's current pose (identity for the world); the
            reference keeps it.

    Raises:
        InvalidInput / NotEnoughCorrespondences / DegenerateGeometry: as ``fit_rigid``, for the
            first sensor whose points cannot give a pose.
    """
    results: dict[str, SensorResult] = {}
    for entry in pairs:
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
    if reference is not None and reference not in results:
        results[reference] = SensorResult(T_world_from_ref.copy(), "reference", 0.0)
    return results


def solve_skeletons(
    reference: str,
    sensors: Sequence[str],
    samples: Samples,
    floor_plane: tuple[float, float, float, float] | None,
    sensor_types: SensorTypes | None = None,
) -> Solution:
    """Every sensor's pose from the bodies it saw at the same instants as the reference.

    Each other sensor is paired with the reference (:func:`solve_with_body_pairing`); the world
    is the reference's floor plane, its origin on the floor under the median pelvis position of
    the walk, its +Z the reference's optical axis on the floor. Without a floor plane the world
    is the reference's camera frame (with a warning).

    Args:
        reference: the sensor whose frame anchors the world (one of ``sensors``).
        sensors: the sensors to solve; ``samples`` holds each of them.
        samples: see :data:`Samples`.
        floor_plane: the reference's latest Kinect ``FloorClipPlane`` (a, b, c, d): unit normal
            in its frame and its height (metres); None when it reports none.
        sensor_types: see :data:`SensorTypes` (a pair with an ``rgb`` sensor: its settings).

    Raises:
        NotEnoughCorrespondences: some sensor could not be paired with the reference (every
            such sensor is named, with its reason).
        InvalidInput: a floor plane with a zero normal or NaN.
    """
    types = sensor_types or {}
    ref_samples = samples[reference]
    T_ref_from: dict[str, Matrix4] = {reference: np.eye(4)}
    relative: dict[str, SensorResult] = {}
    failures: list[str] = []
    for sensor_id in sensors:
        if sensor_id == reference:
            continue
        try:
            relative[sensor_id] = _paired_with_reference(
                ref_samples, samples[sensor_id], types.get(reference), types.get(sensor_id)
            )
        except CalibrationError as exc:
            failures.append(f"{sensor_id}: {exc}")
            continue
        T_ref_from[sensor_id] = relative[sensor_id].T_world_from_sensor
    if failures:
        raise NotEnoughCorrespondences("skeleton calibration failed for " + "; ".join(failures))
    T_world_from_ref, floor, warnings = _skeleton_world(ref_samples, floor_plane)
    results = {
        sensor_id: replace(result, T_world_from_sensor=T_world_from_ref @ T_ref_from[sensor_id])
        for sensor_id, result in relative.items()
    }
    results[reference] = SensorResult(T_world_from_ref, "reference", 0.0)
    return Solution(results, floor, warnings)


def _paired_with_reference(
    ref_samples: Sequence[tuple[Body, ...]],
    other_samples: Sequence[tuple[Body, ...]],
    ref_type: str | None,
    other_type: str | None,
) -> SensorResult:
    """One sensor's pose in the reference's camera frame (``T_world_from_sensor`` holds
    ``T_ref_from_other`` until the world is chosen), with the fit's metrics.

    Raises:
        CalibrationError: the pair cannot be solved (its reason).
    """
    threshold_m, scale_m = pairing_thresholds(ref_type, other_type)
    fit, note = solve_with_body_pairing(
        ref_samples,
        other_samples,
        ransac_threshold_m=threshold_m,
        min_scale_m=scale_m,
    )
    return SensorResult(
        fit.T_ref_from_other,
        "skeleton",
        fit.residual_mm,
        [*fit.warnings, *([note] if note else [])],
        {
            "trust": fit.trust,
            "frames_used": fit.frames_used,
            "joints_used": fit.joints_used,
            "inlier_ratio": round(fit.inlier_ratio, 3),
            "spread_m": round(fit.spread_m, 3),
            "ransac_threshold_m": threshold_m,
            "min_scale_m": scale_m,
        },
    )


def _skeleton_world(
    ref_samples: Sequence[tuple[Body, ...]],
    floor_plane: tuple[float, float, float, float] | None,
) -> tuple[Matrix4, dict[str, Any], tuple[str, ...]]:
    """The world from the reference's floor plane and the walk's median pelvis (see
    :func:`solve_skeletons`): (4, 4) ``T_world_from_ref``, the floor's report, warnings.

    Raises:
        InvalidInput: a floor plane with a zero normal or NaN.
    """
    pelvis = [b.joints_m[JointId.SPINE_BASE] for bodies in ref_samples for b in bodies]
    pelvis_array = np.asarray(pelvis, dtype=np.float64).reshape(-1, 3)
    finite = pelvis_array[np.isfinite(pelvis_array).all(axis=1)]
    centre = np.median(finite, axis=0) if len(finite) else None
    if floor_plane is None:
        warning = (
            "the reference sensor reports no floor plane: the world is its camera frame "
            "until an icp or auto run levels it"
        )
        return np.eye(4), {"source": "none"}, (warning,)
    plane = floor_from_kinect_plane(*floor_plane)
    T_world_from_ref = level_to_floor(np.eye(4), plane, centre_world=centre)
    return (
        T_world_from_ref,
        {"source": "kinect_floor_plane", "sensor_height_m": round(plane.d, 4)},
        (),
    )


def refine_with_depth(
    reference: str,
    clouds: Mapping[str, FloatArray],
    initial: Mapping[str, SensorResult],
    min_overlap: float,
    progress: Progress | None = None,
) -> Solution:
    """Refine every pose with ICP on depth clouds, then level the world with the floor in the
    reference's cloud (keeping the world's yaw and origin).

    Args:
        reference: the sensor whose pose ICP keeps (a key of ``clouds``).
        clouds: sensor id → (N, 3) finite points in its own frame, metres.
        initial: sensor id → the pose to start from (same keys as ``clouds``). Skeleton
            estimates (method ``skeleton``) may move by at most ``SKELETON_ERROR_BOUND``.
        min_overlap: below this share of overlapping points, ICP warns.
        progress: told as ICP gets done (``refine_all``'s levels; the floor fit is the last
            10 %).

    Returns:
        The refined poses (method ``<before>+icp`` where ICP moved them) with ICP metrics;
        ``floor`` None and a warning when the reference's cloud shows no floor.

    Raises:
        InvalidInput: bad clouds or a missing initial pose.
        NoOverlap: a sensor's cloud shares no surface with any other.
    """
    init_poses = {s: initial[s].T_world_from_sensor for s in clouds}
    from_skeleton = any(r.method == "skeleton" for r in initial.values())
    refined = refine_all(
        clouds,
        init_poses,
        reference,
        min_overlap=min_overlap,
        max_correction=SKELETON_ERROR_BOUND if from_skeleton else None,
        progress=scaled_progress(progress, 0.9),
    )
    if progress is not None:  # the floor's RANSAC took about a tenth of a 2-sensor ICP stage
        progress(0.9, "fitting the floor in the reference's depth")
    results: dict[str, SensorResult] = {}
    for sensor_id in clouds:
        icp = refined.get(sensor_id)
        # the reference (no ICP result) keeps its pose
        results[sensor_id] = (
            initial[sensor_id] if icp is None else _with_icp(initial[sensor_id], icp)
        )
    return _levelled_by_floor(results, reference, clouds[reference])


def _with_icp(before: SensorResult, icp: IcpResult) -> SensorResult:
    """A sensor's result after ICP: its pose, method, error and metrics joined to ``before``'s."""
    method = "icp" if icp.applied else before.method
    moved_deg, moved_mm = pose_error(icp.T_target_from_source, before.T_world_from_sensor)
    return SensorResult(
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


def _levelled_by_floor(
    results: dict[str, SensorResult], reference: str, reference_cloud: FloatArray
) -> Solution:
    """Every pose levelled by the floor fitted in the reference's (N, 3) cloud (its own frame,
    metres), the world's yaw and origin kept; unlevelled with a warning when there is no floor."""
    T_world_from_ref = results[reference].T_world_from_sensor
    rotation_ref_from_world = T_world_from_ref[:3, :3].T
    try:
        floor = fit_floor(reference_cloud, up_hint=rotation_ref_from_world[:, 1])
    except CalibrationError as exc:
        warning = f"no floor found in the reference's depth ({exc}); not levelled"
        return Solution(results, None, (warning,))
    T_new_from_ref = level_to_floor(
        T_world_from_ref,
        floor,
        centre_world=np.zeros(3),
        forward_ref=rotation_ref_from_world[:, 2],
    )
    T_new_from_old = T_new_from_ref @ invert(T_world_from_ref)
    tilt = float(np.degrees(np.arccos(np.clip(T_new_from_old[1, 1], -1.0, 1.0))))
    report = {
        "source": "depth",
        "sensor_height_m": round(float(floor.d), 4),
        "rmse_mm": round(floor.rmse_m * 1000, 2),
        "inliers": floor.inlier_count,
        "correction_deg": round(tilt, 3),
        "correction_mm": round(float(abs(T_new_from_old[1, 3])) * 1000, 1),
    }
    levelled = {
        sensor_id: replace(result, T_world_from_sensor=T_new_from_old @ result.T_world_from_sensor)
        for sensor_id, result in results.items()
    }
    return Solution(levelled, report)
