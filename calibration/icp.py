"""ICP refinement of a sensor pose on depth point clouds (open3d, point-to-plane).

open3d is heavy (≈100 MB) and only needed on the server, so it is imported inside the
functions. Clouds are float arrays; nothing here touches files or sockets.

Method (per call of :func:`refine_icp`):

1. Coarse to fine: for each voxel size (default 10, 5, 2.5 cm) both clouds are voxel-averaged,
   the target's normals are estimated (hybrid KD-tree search, radius 2.5 voxels, ≤ 30
   neighbours), and point-to-plane ICP with a Tukey robust kernel (k = one voxel) runs from the
   previous level's result, accepting correspondences up to ``max_correspondence_factor``
   voxels apart (default 2: 20, 10, 5 cm).
2. Judged at the finest level with ``evaluate_registration``: *fitness* (share of source points
   with a target point within the finest distance) and *inlier RMSE*. The refinement is applied
   only if it does not make the truncated cost ``fitness·rmse² + (1 − fitness)·d_max²`` (every
   source point pays its squared distance, capped at ``d_max``) worse than at the initial guess;
   otherwise the initial guess is returned with ``applied = False`` and a warning.
3. *overlap*: share of the source points (finest level) within two finest voxels of the target
   after the accepted transform. Below ``min_overlap`` a warning says the result rests on a
   small shared surface.
4. Degeneracy-aware update: where the shared surfaces do not determine a direction of the
   pose (only floor and a person in common: yaw and horizontal position slide), the ICP
   correction along it is dropped and the initial guess kept (eigen-decomposition of the
   point-to-plane normal matrix, threshold :data:`MIN_EIGEN_RATIO`), with a warning. Without
   this, ICP drifts by centimetres along the floor while its fitness looks fine.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import InvalidInput, NoOverlap
from skelfuse.calibration.icp_constraints import constrained_update
from skelfuse.calibration.open3d_loader import load_open3d
from skelfuse.calibration.rigid import rotation_angle_deg
from skelfuse.protocol.transform import Matrix4, apply, is_rigid

FloatArray = npt.NDArray[np.float64]
Progress = Callable[[float, str], None]
"""Called as work gets done: share of the call's work done (0..1), what it is doing now."""

DEFAULT_VOXELS_M: Final = (0.10, 0.05, 0.025)
MIN_COARSE_FITNESS: Final = 0.02
"""Below this share of source points with a neighbour at the coarsest level: :class:`NoOverlap`."""
MIN_EIGEN_RATIO: Final = 0.1
"""A direction of the pose is "constrained" when its point-to-plane eigenvalue is at least this
share of the largest (``icp_constraints.constrained_update``); with only the floor shared, yaw
and the horizontal position fall to 1–5 % and are left to the initial guess."""


@dataclass(frozen=True, slots=True)
class IcpResult:
    """Result of :func:`refine_icp`.

    ``T_target_from_source``: (4, 4) float64, the refined pose if ``applied``, else the initial
    guess. ``fitness`` / ``inlier_rmse_m``: at the finest level for the returned transform;
    ``initial_fitness`` / ``initial_rmse_m``: the same for the initial guess. ``overlap``: see
    the module docstring. ``correction_deg`` / ``correction_mm``: how far ICP moved the pose
    (0 when not applied). ``constrained_dofs``: how many of the 6 pose directions the shared
    surfaces determine; ICP corrected only those (the rest keep the initial guess).
    """

    T_target_from_source: Matrix4
    fitness: float
    inlier_rmse_m: float
    overlap: float
    applied: bool
    warnings: list[str] = field(default_factory=list)
    initial_fitness: float = 0.0
    initial_rmse_m: float = 0.0
    correction_deg: float = 0.0
    correction_mm: float = 0.0
    constrained_dofs: int = 6


def _cloud_array(points: npt.ArrayLike, name: str) -> FloatArray:
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise InvalidInput(f"{name}: expected an (N, 3) point cloud, got shape {array.shape}")
    if len(array) == 0:
        raise InvalidInput(f"{name}: the point cloud is empty; capture depth again")
    if not np.isfinite(array).all():
        bad = int((~np.isfinite(array).all(axis=1)).sum())
        raise InvalidInput(f"{name}: {bad} of {len(array)} points are NaN/inf; drop them first")
    return array


def _to_o3d(points: FloatArray) -> Any:
    o3d = load_open3d()
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(points)
    return cloud


def scaled_progress(progress: Progress | None, scale: float) -> Progress | None:
    """``progress`` with every fraction multiplied by ``scale`` (a call that is part of a
    larger piece of work)."""
    if progress is None:
        return None
    report = progress
    return lambda fraction, detail: report(scale * fraction, detail)


def _truncated_cost(fitness: float, rmse: float, max_distance: float) -> float:
    return fitness * rmse**2 + (1.0 - fitness) * max_distance**2


def refine_icp(
    source_points: npt.ArrayLike,
    target_points: npt.ArrayLike,
    T_target_from_source_init: npt.ArrayLike,
    *,
    voxel_sizes: Sequence[float] = DEFAULT_VOXELS_M,
    max_correspondence_factor: float = 2.0,
    max_iterations: int = 40,
    min_overlap: float = 0.3,
    min_eigen_ratio: float = MIN_EIGEN_RATIO,
    max_correction: tuple[float, float] | None = None,
    progress: Progress | None = None,
) -> IcpResult:
    """Refine ``T_target_from_source`` by point-to-plane ICP, coarse to fine.

    Args:
        source_points: (N, 3) cloud in the source sensor's frame, metres.
        target_points: (M, 3) cloud in the target frame (the reference sensor or the world).
        T_target_from_source_init: (4, 4) initial guess (skeleton, points or a previous run).
        voxel_sizes: voxel edge per level, coarse to fine (metres).
        max_correspondence_factor: correspondence distance per level, in voxels.
        max_iterations: ICP iterations per level.
        min_overlap: warn below this overlap (share of source points on the target surface).
        min_eigen_ratio: see :data:`MIN_EIGEN_RATIO`; 0 applies the full ICP correction.
        max_correction: (degrees, millimetres): refuse a refinement that moves the pose
            further than this from the initial guess. Pass the initial guess's plausible
            error (e.g. a skeleton estimate's p95): a better-scoring fit that far away is ICP
            locking onto the wrong surfaces, not a correction.
        progress: told after each level, each weighted by 1/voxel (as measured: 0.3-0.7,
            0.9-1.0 and 1.9-2.1 s for 10, 5 and 2.5 cm on the 2-core test machine).

    Returns:
        :class:`IcpResult`.

    Raises:
        InvalidInput: empty clouds, NaN/inf, wrong shapes, a non-rigid initial guess, no levels.
        NoOverlap: (almost) no source point near the target at the coarsest level.
        IcpUnavailable: open3d does not import (see :func:`load_open3d`).
    """
    reg = load_open3d().pipelines.registration
    src_all = _cloud_array(source_points, "source_points")
    tgt_all = _cloud_array(target_points, "target_points")
    init = np.asarray(T_target_from_source_init, dtype=np.float64)
    if not is_rigid(init, atol=1e-5):
        raise InvalidInput("T_target_from_source_init must be a finite rigid 4×4 transform")
    if not voxel_sizes or min(voxel_sizes) <= 0:
        raise InvalidInput(f"voxel_sizes must be positive, got {list(voxel_sizes)}")
    src, tgt, distance, refined = _coarse_to_fine(
        _to_o3d(src_all), _to_o3d(tgt_all), init, voxel_sizes,
        max_correspondence_factor, max_iterations, progress,
    )  # fmt: skip
    refined, dofs = constrained_update(
        np.asarray(src.points), np.asarray(tgt.points), np.asarray(tgt.normals),
        init, refined, distance, min_eigen_ratio,
    )  # fmt: skip
    warnings: list[str] = []
    before = reg.evaluate_registration(src, tgt, distance, init)
    transform, final, applied = _accepted(
        reg, (src, tgt, distance), init, refined, before, max_correction, warnings
    )
    finest = float(min(voxel_sizes))
    overlap = float(reg.evaluate_registration(src, tgt, 2 * finest, transform).fitness)
    warnings += _coverage_warnings(overlap, min_overlap, dofs)
    correction = np.linalg.inv(init) @ transform
    return IcpResult(
        transform,
        float(final.fitness),
        float(final.inlier_rmse),
        overlap,
        applied,
        warnings,
        float(before.fitness),
        float(before.inlier_rmse),
        rotation_angle_deg(correction) if applied else 0.0,
        float(np.linalg.norm(transform[:3, 3] - init[:3, 3])) * 1000.0 if applied else 0.0,
        dofs if applied else 0,
    )


def _coarse_to_fine(
    src_cloud: Any,
    tgt_cloud: Any,
    init: Matrix4,
    voxel_sizes: Sequence[float],
    max_correspondence_factor: float,
    max_iterations: int,
    progress: Progress | None,
) -> tuple[Any, Any, float, Matrix4]:
    """Point-to-plane ICP per voxel level (module docstring, step 1), each from the previous
    level's result. Returns the finest level's (source, target with normals, correspondence
    distance in metres) and the (4, 4) ICP result.

    Raises:
        NoOverlap: too few source points near the target at the coarsest level.
    """
    o3d = load_open3d()
    reg = o3d.pipelines.registration
    transform = init.copy()
    level: tuple[Any, Any, float] | None = None
    work = np.cumsum([1.0 / v for v in voxel_sizes]) / sum(1.0 / v for v in voxel_sizes)
    for number, voxel in enumerate(voxel_sizes):
        src = src_cloud.voxel_down_sample(voxel)
        tgt = tgt_cloud.voxel_down_sample(voxel)
        tgt.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
        distance = max_correspondence_factor * voxel
        if number == 0:
            coarse = reg.evaluate_registration(src, tgt, distance, init)
            if coarse.fitness < MIN_COARSE_FITNESS:
                raise NoOverlap(
                    f"at the initial guess only {coarse.fitness:.1%} of the source points are "
                    f"within {distance * 100:.0f} cm of the target cloud: the sensors do not see "
                    "the same surfaces, or the initial guess is far off (recalibrate with "
                    "skeletons or points first)"
                )
        estimation = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=voxel))
        criteria = reg.ICPConvergenceCriteria(
            relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=max_iterations
        )
        result = reg.registration_icp(src, tgt, distance, transform, estimation, criteria)
        transform = np.asarray(result.transformation, dtype=np.float64).copy()
        level = (src, tgt, distance)
        if progress is not None:
            progress(float(work[number]), f"level {number + 1} of {len(voxel_sizes)} done")
    assert level is not None  # voxel_sizes is non-empty
    return (*level, transform)


def _accepted(
    reg: Any,
    level: tuple[Any, Any, float],
    init: Matrix4,
    refined: Matrix4,
    before: Any,
    max_correction: tuple[float, float] | None,
    warnings: list[str],
) -> tuple[Matrix4, Any, bool]:
    """The (4, 4) refined pose if it does not raise the truncated cost at the finest ``level``
    (module docstring, step 2) and moves no further than ``max_correction`` (degrees,
    millimetres); else the initial guess, with a warning appended saying why.

    Returns:
        (the pose, its evaluation at the finest level, whether the refinement was applied);
        ``before`` is the initial guess's evaluation.
    """
    src, tgt, distance = level
    after = reg.evaluate_registration(src, tgt, distance, refined)
    cost_before = _truncated_cost(before.fitness, before.inlier_rmse, distance)
    cost_after = _truncated_cost(after.fitness, after.inlier_rmse, distance)
    if not (bool(np.isfinite(refined).all()) and cost_after <= cost_before * (1 + 1e-9)):
        warnings.append(
            "ICP made the fit worse (fitness "
            f"{before.fitness:.2f}→{after.fitness:.2f}, RMSE {before.inlier_rmse * 1000:.1f}→"
            f"{after.inlier_rmse * 1000:.1f} mm): kept the initial pose"
        )
        return init.copy(), before, False
    if max_correction is not None:
        moved_deg = rotation_angle_deg(np.linalg.inv(init) @ refined)
        moved_mm = float(np.linalg.norm(refined[:3, 3] - init[:3, 3])) * 1000.0
        if moved_deg > max_correction[0] or moved_mm > max_correction[1]:
            warnings.append(
                f"ICP wanted to move the pose by {moved_deg:.1f}° / {moved_mm:.0f} mm, more "
                f"than the initial guess can be off ({max_correction[0]:.1f}° / "
                f"{max_correction[1]:.0f} mm): kept the initial pose"
            )
            return init.copy(), before, False
    return refined, after, True


def _coverage_warnings(overlap: float, min_overlap: float, dofs: int) -> list[str]:
    """Warnings for a small ``overlap`` (share, 0..1) and for pose directions left to the
    initial guess (``dofs`` of 6 constrained)."""
    warnings = []
    if overlap < min_overlap:
        warnings.append(
            f"small overlap ({overlap:.0%} of this sensor's points lie on surfaces the target "
            f"sees, below {min_overlap:.0%}): the refinement rests on little shared surface; "
            "check the result, or add a sensor in between"
        )
    if dofs < 6:
        warnings.append(
            f"the shared surfaces determine only {dofs} of the 6 pose directions (e.g. mostly "
            "floor): ICP corrected those (tilt and height when it is the floor) and kept the "
            "initial guess for the rest"
        )
    return warnings


def refine_all(
    clouds_sensor: Mapping[str, npt.ArrayLike],
    T_world_from_sensor_init: Mapping[str, npt.ArrayLike],
    reference: str,
    *,
    second_pass: bool = True,
    progress: Progress | None = None,
    **icp_options: Any,
) -> dict[str, IcpResult]:
    """Refine every non-reference sensor's pose against the others' clouds in the world.

    Pass 1 refines each sensor against the reference sensor's cloud alone (the reference never
    moves; this cannot drift). Pass 2 (``second_pass``) refines each sensor again against the
    union of all other sensors' clouds placed with the poses from pass 1: a sensor that shares
    little with the reference but much with a neighbour gets constrained too. A sensor that
    has no overlap with the reference in pass 1 goes straight to pass 2. Each pass keeps its
    result only if it does not make that sensor's fit worse (see :func:`refine_icp`).

    Args:
        clouds_sensor: sensor id → (N, 3) cloud in that sensor's frame, metres.
        T_world_from_sensor_init: sensor id → (4, 4) initial pose (same keys).
        reference: the sensor whose pose is kept as is.
        second_pass: run pass 2.
        progress: told after each level of each sensor's refinement; every refinement of a
            pass counts the same (pass 1 and pass 2 each one per non-reference sensor).
        icp_options: passed to :func:`refine_icp`.

    Returns:
        sensor id → :class:`IcpResult` for every non-reference sensor (``T_target_from_source``
        is its refined ``T_world_from_sensor``).

    Raises:
        InvalidInput: missing keys or reference, bad clouds.
        NoOverlap: a sensor overlaps neither the reference nor any other sensor.
    """
    if reference not in clouds_sensor:
        raise InvalidInput(f"reference {reference!r} has no cloud; got {sorted(clouds_sensor)}")
    missing = set(clouds_sensor) - set(T_world_from_sensor_init)
    if missing:
        raise InvalidInput(f"no initial pose for {sorted(missing)}")
    clouds = {k: _cloud_array(v, f"cloud of {k}") for k, v in clouds_sensor.items()}
    poses = {k: np.asarray(T_world_from_sensor_init[k], dtype=np.float64) for k in clouds}
    others = len(clouds) - 1
    passes = _PassProgress(progress, max(1, others * (2 if second_pass else 1)))
    results, pending = _against_reference(clouds, poses, reference, passes, icp_options)
    if second_pass or pending:
        for sensor in sorted(clouds):
            if sensor == reference or (not second_pass and sensor not in pending):
                continue
            _against_all_others(clouds, poses, sensor, results, passes, icp_options)
    return results


@dataclass
class _PassProgress:
    """``refine_all``'s progress: every refinement of a pass counts one of ``total``."""

    progress: Progress | None
    total: int
    done: int = 0

    def step(self, sensor: str, pass_number: int) -> Progress | None:
        """The progress of the next refinement, ``sensor``'s in pass ``pass_number``."""
        if self.progress is None:
            return None
        report, base, total = self.progress, self.done, self.total

        def level(fraction: float, detail: str) -> None:
            share = min(1.0, (base + fraction) / total)
            report(share, f"{sensor}, pass {pass_number}: {detail}")

        return level


def _against_reference(
    clouds: Mapping[str, FloatArray],
    poses: dict[str, FloatArray],
    reference: str,
    passes: _PassProgress,
    icp_options: Mapping[str, Any],
) -> tuple[dict[str, IcpResult], list[str]]:
    """Pass 1: each non-reference sensor against the reference's cloud alone; ``poses``
    (sensor id → (4, 4) ``T_world_from_sensor``) take the results. Returns the results and the
    sensors that do not overlap the reference (left to pass 2)."""
    target_ref = apply(poses[reference], clouds[reference])
    results: dict[str, IcpResult] = {}
    pending: list[str] = []
    for sensor in sorted(clouds):
        if sensor == reference:
            continue
        try:
            results[sensor] = refine_icp(
                clouds[sensor], target_ref, poses[sensor], progress=passes.step(sensor, 1),
                **icp_options,
            )  # fmt: skip
        except NoOverlap:
            passes.done += 1
            pending.append(sensor)
            continue
        passes.done += 1
        poses[sensor] = results[sensor].T_target_from_source
    return results, pending


def _against_all_others(
    clouds: Mapping[str, FloatArray],
    poses: dict[str, FloatArray],
    sensor: str,
    results: dict[str, IcpResult],
    passes: _PassProgress,
    icp_options: Mapping[str, Any],
) -> None:
    """Pass 2 for ``sensor``: against the union of all other clouds placed with ``poses``; the
    result replaces pass 1's in ``results`` and ``poses`` if applied (or if pass 1 had none).

    Raises:
        NoOverlap: the sensor overlaps no other sensor, and did not overlap the reference.
    """
    target = np.concatenate([apply(poses[k], clouds[k]) for k in sorted(clouds) if k != sensor])
    previous = results.get(sensor)
    try:
        refined = refine_icp(
            clouds[sensor], target, poses[sensor], progress=passes.step(sensor, 2), **icp_options
        )
    except NoOverlap:
        if previous is None:
            raise
        return
    finally:
        passes.done += 1
    if previous is None or refined.applied:
        if previous is not None:
            refined.warnings[:0] = [w for w in previous.warnings if "overlap" in w]
        results[sensor] = refined
        poses[sensor] = refined.T_target_from_source
