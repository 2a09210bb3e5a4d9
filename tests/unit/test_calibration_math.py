"""Calibration math: rigid fit, skeleton solver, floor, levelling, ICP (seeded, fast)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.sim.kinect_model import SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.room import Box, Room, capture_point_cloud, default_room
from skelfuse.calibration.errors import (
    CalibrationError,
    DegenerateGeometry,
    InvalidInput,
    NoOverlap,
    NotEnoughCorrespondences,
)
from skelfuse.calibration.floor import (
    FloorFit,
    fit_floor,
    floor_error,
    floor_from_kinect_plane,
    level_to_floor,
)
from skelfuse.calibration.icp import refine_all, refine_icp
from skelfuse.calibration.rigid import fit_rigid, pose_error, rotation_angle_deg
from skelfuse.calibration.skeleton_pose import solve_from_skeletons
from skelfuse.protocol.transform import apply, invert, look_at_pose, pose_from_position_yaw_pitch

F64 = npt.NDArray[np.float64]


def random_pose(
    rng: np.random.Generator, angle_deg: float | None = None, shift_m: float = 2.0
) -> F64:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.radians(angle_deg if angle_deg is not None else rng.uniform(0, 180))
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    pose = np.eye(4)
    pose[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    pose[:3, 3] = rng.uniform(-shift_m, shift_m, size=3)
    return pose


# --- rigid ------------------------------------------------------------------------------------


def test_errors_share_a_base() -> None:
    for error in (InvalidInput, NotEnoughCorrespondences, DegenerateGeometry, NoOverlap):
        assert issubclass(error, CalibrationError)


def test_fit_rigid_recovers_random_transforms_exactly() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        truth = random_pose(rng)
        src = rng.uniform(-2, 2, size=(int(rng.integers(3, 30)), 3))
        fit = fit_rigid(src, apply(truth, src))
        assert np.abs(fit.T_dst_from_src - truth).max() < 1e-9
        assert fit.rmse_m < 1e-9 and fit.residuals_m.shape == (len(src),)


def test_fit_rigid_weights_ignore_an_outlier() -> None:
    rng = np.random.default_rng(1)
    truth = random_pose(rng)
    src = rng.uniform(-1, 1, size=(6, 3))
    dst = apply(truth, src)
    dst[0] += [0.5, 0.0, 0.0]
    weighted = fit_rigid(src, dst, weights=[0, 1, 1, 1, 1, 1])
    assert np.abs(weighted.T_dst_from_src - truth).max() < 1e-9
    assert weighted.residuals_m[0] == pytest.approx(0.5)
    assert pose_error(fit_rigid(src, dst).T_dst_from_src, truth)[1] > 10


def test_fit_rigid_never_returns_a_reflection() -> None:
    rng = np.random.default_rng(2)
    src = rng.uniform(-1, 1, size=(10, 3))
    dst = src * [-1.0, 1.0, 1.0]  # a mirror image: the best proper rotation, not a reflection
    assert np.linalg.det(fit_rigid(src, dst).T_dst_from_src[:3, :3]) == pytest.approx(1.0)


def test_fit_rigid_bad_input() -> None:
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(NotEnoughCorrespondences, match="got 2"):
        fit_rigid(pts[:2], pts[:2])
    line = np.outer(np.arange(5.0), [1.0, 2.0, 0.5])
    with pytest.raises(DegenerateGeometry, match="collinear"):
        fit_rigid(line, line)
    with pytest.raises(DegenerateGeometry, match="coincide"):
        fit_rigid(np.zeros((4, 3)), np.zeros((4, 3)))
    nan = pts.copy()
    nan[1, 1] = np.nan
    with pytest.raises(InvalidInput, match="NaN"):
        fit_rigid(nan, pts)
    with pytest.raises(InvalidInput, match="shape"):
        fit_rigid(pts[:, :2], pts[:, :2])
    with pytest.raises(InvalidInput, match="same shape"):
        fit_rigid(pts, pts[:3])


def test_pose_error_helpers() -> None:
    pose = pose_from_position_yaw_pitch((0.0, 0.0, 0.0), 30.0)
    assert rotation_angle_deg(pose) == pytest.approx(30.0)
    moved = pose.copy()
    moved[:3, 3] += [0.003, 0.004, 0.0]
    assert pose_error(moved, pose) == pytest.approx((0.0, 5.0), abs=1e-6)


# --- skeleton ---------------------------------------------------------------------------------


def observe(kinect: SimulatedKinect, performer: ProceduralPerformer, times: F64) -> tuple[F64, F64]:
    joints = np.full((len(times), 25, 3), np.nan)
    states = np.zeros((len(times), 25))
    for i, t in enumerate(times):
        seen = kinect.observe(performer.joints_at(float(t)), float(t))
        if seen:
            joints[i], states[i] = seen[0].joints_m, seen[0].states
    return joints, states


@pytest.mark.parametrize("angle_deg", [60.0, 150.0])
def test_skeleton_solver_recovers_relative_pose(angle_deg: float) -> None:
    a = np.radians(angle_deg)
    pose_ref = look_at_pose((0.0, 1.0, 3.0), (0.0, 0.9, 0.0))
    pose_other = look_at_pose((3.0 * np.sin(a), 1.7, 3.0 * np.cos(a)), (0.0, 0.9, 0.0))
    performer = ProceduralPerformer(1)
    times = np.arange(0.0, 15.0, 1 / 30)
    ref = observe(SimulatedKinect(pose_ref, seed=1), performer, times)
    other = observe(SimulatedKinect(pose_other, seed=2), performer, times)
    fit = solve_from_skeletons(*ref, *other)
    rot, trans = pose_error(fit.T_ref_from_other, invert(pose_ref) @ pose_other)
    assert rot < 2.0 and trans < 40.0
    assert fit.trust in ("medium", "high") and fit.frames_used > 200
    assert 0 < fit.residual_mm < 60 and fit.inlier_ratio > 0.5


def test_skeleton_solver_rejects_a_person_standing_still() -> None:
    pose_ref = look_at_pose((0.0, 1.0, 3.0), (0.0, 0.9, 0.0))
    pose_other = look_at_pose((3.0, 1.0, 0.0), (0.0, 0.9, 0.0))
    performer = ProceduralPerformer(1)
    times = np.full(300, 0.0) + np.arange(300) * 1e-4  # 300 frames, the person does not move
    ref = observe(SimulatedKinect(pose_ref, seed=1), performer, times)
    other = observe(SimulatedKinect(pose_other, seed=2), performer, times)
    with pytest.raises(DegenerateGeometry, match="walk around"):
        solve_from_skeletons(*ref, *other)


def test_skeleton_solver_bad_input() -> None:
    joints = np.full((50, 25, 3), np.nan)
    states = np.zeros((50, 25))
    with pytest.raises(NotEnoughCorrespondences, match="both sensors"):
        solve_from_skeletons(joints, states, joints, states)
    with pytest.raises(InvalidInput, match="shape"):
        solve_from_skeletons(joints[:, :20], states, joints, states)
    with pytest.raises(InvalidInput, match="same instants"):
        solve_from_skeletons(joints, states, joints[:40], states[:40])


# --- floor ------------------------------------------------------------------------------------


def synthetic_room_cloud(rng: np.random.Generator) -> F64:
    """World points: floor, two walls and two box tops (world frame, +Y up)."""
    floor = np.c_[rng.uniform(-3, 3, 3000), np.zeros(3000), rng.uniform(-3, 3, 3000)]
    wall_x = np.c_[np.full(2500, 3.0), rng.uniform(0, 2.5, 2500), rng.uniform(-3, 3, 2500)]
    wall_z = np.c_[rng.uniform(-3, 3, 2500), rng.uniform(0, 2.5, 2500), np.full(2500, -3.0)]
    box_top = np.c_[rng.uniform(1, 2.5, 1500), np.full(1500, 0.8), rng.uniform(-2, 0, 1500)]
    table = np.c_[rng.uniform(-2, -0.5, 1500), np.full(1500, 0.45), rng.uniform(0, 2, 1500)]
    points = np.concatenate([floor, wall_x, wall_z, box_top, table])
    return points + rng.normal(scale=0.004, size=points.shape)


def test_fit_floor_finds_the_floor_not_a_wall_or_box() -> None:
    rng = np.random.default_rng(4)
    pose = pose_from_position_yaw_pitch((0.5, 1.6, -0.5), 20.0, 25.0)  # pitched down
    cloud = apply(invert(pose), synthetic_room_cloud(rng))
    fit = fit_floor(cloud, up_hint=(0.0, 1.0, 0.0))
    tilt, height_mm = floor_error(fit, pose)
    assert tilt < 0.3 and abs(height_mm) < 5
    assert fit.inlier_count > 2500 and fit.rmse_m < 0.02


def test_fit_floor_on_a_rendered_cloud_and_from_the_kinect_plane() -> None:
    pose = look_at_pose((1.0, 1.8, 2.5), (0.0, 0.8, 0.0))
    cloud = capture_point_cloud(default_room(), None, pose, np.random.default_rng(5))
    tilt, height_mm = floor_error(fit_floor(cloud), pose)
    assert tilt < 0.5 and abs(height_mm) < 10
    plane = SimulatedKinect(pose).floor_plane()
    kinect = floor_from_kinect_plane(*plane)
    assert floor_error(kinect, pose) == pytest.approx((0.0, 0.0), abs=1e-6)
    with pytest.raises(InvalidInput, match="not detected"):
        floor_from_kinect_plane(0.0, 0.0, 0.0, 0.0)


def test_fit_floor_bad_input() -> None:
    with pytest.raises(NotEnoughCorrespondences):
        fit_floor(np.zeros((10, 3)))
    with pytest.raises(InvalidInput):
        fit_floor(np.zeros((10, 2)))
    wall = np.c_[np.zeros(1000), np.random.default_rng(0).uniform(0, 2, (1000, 2))]
    with pytest.raises(DegenerateGeometry):
        fit_floor(wall)


def test_level_to_floor_puts_the_floor_at_y0() -> None:
    pose_true = pose_from_position_yaw_pitch((1.0, 1.4, -2.0), 140.0, 20.0)
    floor = floor_from_kinect_plane(*SimulatedKinect(pose_true).floor_plane())
    # The current world is the reference sensor's own frame (identity); centre: 2 m ahead.
    centre = np.array([0.0, 0.0, 2.0])
    leveled = level_to_floor(np.eye(4), floor, centre_world=centre)
    floor_points_world = np.array([[0.0, 0, 0], [1, 0, 3], [-2, 0, 1]])
    floor_points_ref = apply(invert(pose_true), floor_points_world)
    assert np.abs(apply(leveled, floor_points_ref)[:, 1]).max() < 1e-9
    assert leveled[1, 3] == pytest.approx(1.4)  # the sensor's height
    origin = apply(leveled, centre)
    assert origin[0] == pytest.approx(0.0, abs=1e-9) and origin[2] == pytest.approx(0.0, abs=1e-9)
    forward = leveled[:3, :3] @ [0.0, 0.0, 1.0]
    assert forward[0] == pytest.approx(0.0, abs=1e-9) and forward[2] > 0  # looks along +Z
    assert isinstance(floor, FloorFit)


# --- ICP --------------------------------------------------------------------------------------

CORNER_A = look_at_pose((1.0, 1.5, 0.5), (3.5, 0.6, 3.0))
CORNER_B = look_at_pose((2.0, 1.2, -0.5), (3.2, 0.6, 3.2))


@pytest.fixture(scope="module")
def corner_clouds() -> tuple[F64, F64]:
    rng = np.random.default_rng(3)
    room = default_room()
    cloud_a = capture_point_cloud(room, None, CORNER_A, rng).astype(np.float64)
    cloud_b = capture_point_cloud(room, None, CORNER_B, rng).astype(np.float64)
    return cloud_a, cloud_b


def perturbed(truth: F64) -> F64:
    yaw = pose_from_position_yaw_pitch((0.03, 0.03, -0.03), 3.0)
    result: F64 = truth @ yaw
    return result


def test_icp_recovers_a_3deg_5cm_perturbation(corner_clouds: tuple[F64, F64]) -> None:
    cloud_a, cloud_b = corner_clouds
    truth = invert(CORNER_A) @ CORNER_B
    init = perturbed(truth)
    assert pose_error(init, truth)[0] == pytest.approx(3.0)
    result = refine_icp(cloud_b, cloud_a, init)
    rot, trans = pose_error(result.T_target_from_source, truth)
    assert result.applied and rot < 0.5 and trans < 10.0
    assert result.fitness > result.initial_fitness and result.overlap > 0.3
    assert result.constrained_dofs == 6 and result.warnings == []


def test_icp_refuses_to_apply_a_worse_result(corner_clouds: tuple[F64, F64]) -> None:
    cloud_a, cloud_b = corner_clouds
    truth = invert(CORNER_A) @ CORNER_B
    # Starting from the truth with correspondences so loose that ICP is pulled off it would be
    # worse; the fine-level check keeps the truth (or ICP stays on it).
    result = refine_icp(
        cloud_b, cloud_a, truth, voxel_sizes=(0.3, 0.2), max_correspondence_factor=4
    )
    rot, trans = pose_error(result.T_target_from_source, truth)
    if not result.applied:
        assert rot == 0.0 and trans == 0.0 and "worse" in result.warnings[0]
    else:
        assert result.inlier_rmse_m <= result.initial_rmse_m * 1.05
    # A cloud that matches nothing better than its start: ICP must not move it for the worse.
    noise = np.random.default_rng(9).uniform(-0.02, 0.02, size=cloud_a.shape)
    same = refine_icp(cloud_a + noise, cloud_a, np.eye(4))
    assert pose_error(same.T_target_from_source, np.eye(4))[1] < 5.0


def test_icp_warns_on_small_overlap(corner_clouds: tuple[F64, F64]) -> None:
    cloud_a, cloud_b = corner_clouds
    truth = invert(CORNER_A) @ CORNER_B
    world_b = apply(truth, cloud_b)
    part = world_b[world_b[:, 0] > np.quantile(world_b[:, 0], 0.8)]
    part_a = cloud_a[cloud_a[:, 0] < np.quantile(cloud_a[:, 0], 0.3)]
    result = refine_icp(cloud_b, np.concatenate([part_a, part]), truth, min_overlap=0.5)
    assert any("small overlap" in w for w in result.warnings)


def test_icp_bad_input(corner_clouds: tuple[F64, F64]) -> None:
    cloud_a, cloud_b = corner_clouds
    with pytest.raises(InvalidInput, match="empty"):
        refine_icp(np.zeros((0, 3)), cloud_a, np.eye(4))
    nan = cloud_b.copy()
    nan[0, 0] = np.nan
    with pytest.raises(InvalidInput, match="NaN"):
        refine_icp(nan, cloud_a, np.eye(4))
    with pytest.raises(NoOverlap):
        refine_icp(cloud_b + [50.0, 0.0, 0.0], cloud_a, np.eye(4))


def test_refine_all_against_the_reference(corner_clouds: tuple[F64, F64]) -> None:
    cloud_a, cloud_b = corner_clouds
    world_from = {"a": CORNER_A, "b": perturbed(CORNER_B)}
    results = refine_all({"a": cloud_a, "b": cloud_b}, world_from, "a", second_pass=False)
    assert set(results) == {"b"}
    rot, trans = pose_error(results["b"].T_target_from_source, CORNER_B)
    assert rot < 0.5 and trans < 10.0


def test_floor_only_overlap_keeps_the_horizontal_guess() -> None:
    room = Room(boxes=(Box((10.0, 0.0, 10.0), (10.5, 0.5, 10.5)),))  # nothing but floor in range
    rng = np.random.default_rng(6)
    pose_a = look_at_pose((0.0, 1.5, 2.0), (0.0, 0.0, -1.0))
    pose_b = look_at_pose((2.0, 1.2, 0.0), (-1.0, 0.0, 0.0))
    cloud_a = capture_point_cloud(room, None, pose_a, rng)
    cloud_b = capture_point_cloud(room, None, pose_b, rng)
    truth = invert(pose_a) @ pose_b
    result = refine_icp(cloud_b, cloud_a, perturbed(truth))
    assert result.constrained_dofs == 3 and any("only 3" in w for w in result.warnings)
    # Tilt and height are fixed by the floor; the guess's horizontal error stays about the same.
    est_up = result.T_target_from_source[:3, :3].T @ invert(pose_a)[:3, :3] @ [0, 1, 0]
    true_up = invert(pose_b)[:3, :3] @ [0, 1, 0]
    assert np.degrees(np.arccos(np.clip(est_up @ true_up, -1, 1))) < 0.3
