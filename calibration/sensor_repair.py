"""One sensor solved again against the others, whose poses stay as they are (drift repair: a
bumped or moved sensor, docs/calibration.md): its skeletons paired with each fixed sensor's
(:func:`solve_sensor`), then ICP against their depth clouds (:func:`refine_sensor_with_depth`).

Pure functions, as :mod:`skelfuse.calibration.solvers` (whose result types they share); the
server's run orchestration calls them in its worker.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from skelfuse.calibration.body_pairing import pairing_thresholds, solve_with_body_pairing
from skelfuse.calibration.errors import CalibrationError, InvalidInput, NotEnoughCorrespondences
from skelfuse.calibration.icp import Progress, refine_icp
from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.skeleton_pose import SKELETON_ERROR_BOUND
from skelfuse.calibration.solvers import FloatArray, Samples, SensorResult, SensorTypes
from skelfuse.protocol.transform import Matrix4, apply

_TRUST_RANK = {"low": 0, "medium": 1, "high": 2}


def solve_sensor(
    sensor: str,
    fixed: Mapping[str, Matrix4],
    samples: Samples,
    sensor_types: SensorTypes | None = None,
) -> SensorResult:
    """One sensor's pose from the bodies it saw with the others, whose poses stay fixed.

    The sensor is paired with each fixed sensor (:func:`solve_with_body_pairing`); each pairing
    gives ``T_world_from_sensor = T_world_from_other · T_other_from_sensor``; the most trusted
    one (then the one with most joints) wins, and every pairing is reported in the metrics.

    Args:
        sensor: the sensor to solve (a key of ``samples``).
        fixed: other sensor id → its (4, 4) ``T_world_from_sensor`` (metres), kept as is.
        samples: see :data:`Samples` (``sensor`` and every key of ``fixed``).
        sensor_types: see :data:`SensorTypes` (a pair with an ``rgb`` sensor: its settings).

    Raises:
        NotEnoughCorrespondences: no fixed sensor could be paired with it (each reason named).
    """
    candidates: list[tuple[tuple[int, int], str, Matrix4, Any, tuple[float, float]]] = []
    failures: list[str] = []
    types = sensor_types or {}
    for other, T_world_from_other in sorted(fixed.items()):
        threshold_m, scale_m = pairing_thresholds(types.get(other), types.get(sensor))
        try:
            fit, _ = solve_with_body_pairing(
                samples[other], samples[sensor], ransac_threshold_m=threshold_m, min_scale_m=scale_m
            )
        except CalibrationError as exc:
            failures.append(f"{other}: {exc}")
            continue
        rank = (_TRUST_RANK[fit.trust], fit.joints_used)
        settings = (threshold_m, scale_m)
        candidates.append((rank, other, T_world_from_other @ fit.T_ref_from_other, fit, settings))
    if not candidates:
        raise NotEnoughCorrespondences(
            f"{sensor} could not be solved against any other sensor: " + "; ".join(failures)
        )
    _, partner, pose, fit, (threshold_m, scale_m) = max(candidates, key=lambda c: c[0])
    partners = {
        other: {
            "trust": f.trust,
            "residual_mm": round(f.residual_mm, 2),
            "joints_used": f.joints_used,
            "disagreement_deg_mm": [round(x, 2) for x in pose_error(T, pose)],
        }
        for _, other, T, f, _ in candidates
    }
    return SensorResult(
        pose,
        "sensor",
        fit.residual_mm,
        [*fit.warnings, *(f"not paired with {failure}" for failure in failures)],
        {
            "against": partner,
            "trust": fit.trust,
            "frames_used": fit.frames_used,
            "joints_used": fit.joints_used,
            "spread_m": round(fit.spread_m, 3),
            "ransac_threshold_m": threshold_m,
            "min_scale_m": scale_m,
            "partners": partners,
        },
    )


def refine_sensor_with_depth(
    sensor: str,
    clouds: Mapping[str, FloatArray],
    initial: SensorResult,
    fixed: Mapping[str, Matrix4],
    min_overlap: float,
    progress: Progress | None = None,
) -> SensorResult:
    """Refine one sensor's pose by ICP against the others' clouds placed with their fixed poses.

    Args:
        sensor: the sensor to refine (a key of ``clouds``).
        clouds: sensor id → (N, 3) finite points in its own frame, metres (``sensor`` and at
            least one key of ``fixed``).
        initial: the pose to start from; a skeleton estimate (method ``sensor``) may move by at
            most ``SKELETON_ERROR_BOUND``.
        fixed: other sensor id → (4, 4) ``T_world_from_sensor``, kept as is.
        min_overlap: below this share of overlapping points, ICP warns.
        progress: told after each ICP level.

    Raises:
        InvalidInput: bad clouds, or no fixed sensor's cloud.
        NoOverlap: the sensor's cloud shares no surface with the others'.
        IcpUnavailable: open3d cannot load.
    """
    others = [apply(fixed[o], clouds[o]) for o in sorted(fixed) if o in clouds]
    if not others:
        raise InvalidInput(f"no depth cloud from another sensor to refine {sensor} against")
    icp = refine_icp(
        clouds[sensor],
        np.concatenate(others),
        initial.T_world_from_sensor,
        min_overlap=min_overlap,
        max_correction=SKELETON_ERROR_BOUND if initial.method == "sensor" else None,
        progress=progress,
    )
    return SensorResult(
        icp.T_target_from_source,
        f"{initial.method}+icp" if icp.applied else initial.method,
        icp.inlier_rmse_m * 1000.0 if icp.applied else initial.residual_mm,
        [*initial.warnings, *icp.warnings],
        {
            **initial.metrics,
            "icp_applied": icp.applied,
            "fitness": round(icp.fitness, 4),
            "overlap": round(icp.overlap, 4),
            "correction_deg": round(icp.correction_deg, 3),
            "correction_mm": round(icp.correction_mm, 1),
        },
    )
