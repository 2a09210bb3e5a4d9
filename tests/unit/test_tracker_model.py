"""The depth body tracker error model: each structural effect, measured with fixed seeds."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.sim.kinect_model import Observation
from skelfuse.agent.sim.performer import standing_pose
from skelfuse.agent.sim.tracker_model import (
    SWAPPABLE_LIMBS,
    DepthTrackerParams,
    SimulatedDepthTracker,
    lean_turn,
    limb_swap,
)
from skelfuse.protocol.skeleton import MIRROR_PERMUTATION, JointId, TrackingState
from skelfuse.protocol.transform import apply, invert, look_at_pose

J = JointId
F64 = npt.NDArray[np.float64]
MIRROR = np.array(MIRROR_PERMUTATION)
IDENTITY = np.arange(25)
# Everything off but what a test turns on: no lean, bias, swaps, glitches, losses, noise.
BARE = DepthTrackerParams(
    depth_noise_per_m2=0.0,
    across_noise_rad=0.0,
    body_scale_sd=0.0,
    lean_max_deg=0.0,
    side_depth_bias_m=0.0,
    limb_swap_rate_hz=0.0,
    occlusion_pull=0.0,
    occlusion_noise_m=0.0,
    glitch_rate_hz=0.0,
    dropout_rate_hz=0.0,
)


def facing(body: F64, heading: float) -> F64:
    """Rotate a standing body (facing +Z) to face ``heading`` (0 = +Z, π = −Z)."""
    c, s = math.cos(heading), math.sin(heading)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    centre = body[J.SPINE_BASE] * [1, 0, 1]
    out: F64 = (body - centre) @ rot.T + centre
    return out


def tracker(
    params: DepthTrackerParams, distance: float = 2.5, seed: int = 3
) -> SimulatedDepthTracker:
    """A tracker at (0, 1, ``distance``) looking at the origin's vertical (the person)."""
    return SimulatedDepthTracker(look_at_pose((0.0, 1.0, distance), (0.0, 1.0, 0.0)), params, seed)


def watch(sensor: SimulatedDepthTracker, body: F64, frames: int, dt: float) -> list[Observation]:
    return [sensor.observe(body[None], i * dt)[0] for i in range(frames)]


def along_ray(sensor: SimulatedDepthTracker, observation: Observation, truth: F64) -> F64:
    """(25,) signed error (m) along each true joint's ray, + away from the sensor."""
    true_sensor = apply(invert(sensor.T_world_from_sensor), truth)
    put_right = observation.labels_put_right().astype(np.float64)
    rays = true_sensor / np.linalg.norm(true_sensor, axis=1, keepdims=True)
    out: F64 = np.sum((put_right - true_sensor) * rays, axis=1)
    return out


def test_depth_noise_grows_with_the_square_of_distance_and_is_correlated_in_time() -> None:
    params = replace(BARE, depth_noise_per_m2=0.004, across_noise_rad=0.002)
    body = standing_pose()
    spreads = []
    for distance in (1.5, 3.0):
        sensor = tracker(params, distance)
        # 1 s apart: the AR(1) (τ 0.3 s) forgets between samples, so the spread is the σ.
        samples = [along_ray(sensor, o, body)[J.SPINE_MID] for o in watch(sensor, body, 400, 1.0)]
        spreads.append(float(np.std(samples)))
    assert spreads[1] / spreads[0] == pytest.approx(4.0, rel=0.15), "σ ∝ d²: ×4 at twice the range"
    sensor = tracker(params, 3.0)
    observations = watch(sensor, body, 600, 1 / 30)
    depth = np.array([along_ray(sensor, o, body)[J.SPINE_MID] for o in observations])
    true_sensor = apply(invert(sensor.T_world_from_sensor), body)[J.SPINE_MID]
    across = np.array([o.joints_m[J.SPINE_MID, 0] - true_sensor[0] for o in observations])
    # exp(−(1/30)/0.3) ≈ 0.89 along the ray; the across noise is white.
    assert np.corrcoef(depth[:-1], depth[1:])[0, 1] > 0.75
    assert abs(np.corrcoef(across[:-1], across[1:])[0, 1]) < 0.15


def test_side_views_are_pushed_along_the_ray_more_side_on_and_more_on_the_far_side() -> None:
    params = replace(BARE, side_depth_bias_m=0.04, far_side_gain=1.5)
    push = {}
    far_over_near = 0.0
    for yaw_deg in (0.0, 45.0, 90.0):
        body = facing(standing_pose(), math.radians(yaw_deg))
        sensor = tracker(params)
        observation = watch(sensor, body, 1, 1 / 30)[0]
        error = along_ray(sensor, observation, body)
        push[yaw_deg] = float(error[J.SPINE_MID])
        if yaw_deg == 90.0:
            to_sensor = sensor.position_m
            left_far = np.linalg.norm(body[J.SHOULDER_LEFT] - to_sensor) > np.linalg.norm(
                body[J.SHOULDER_RIGHT] - to_sensor
            )
            far, near = (J.ELBOW_LEFT, J.ELBOW_RIGHT) if left_far else (J.ELBOW_RIGHT, J.ELBOW_LEFT)
            far_over_near = float(error[far] / error[near])
    assert abs(push[0.0]) < 1e-6, "no push in a frontal view"
    assert push[45.0] == pytest.approx(0.04 * 0.5, abs=1e-3)  # sin² 45° = 0.5
    assert push[90.0] == pytest.approx(0.04, abs=1e-3)
    assert far_over_near == pytest.approx(2.5, rel=0.05)


def swapped_frames(observations: list[Observation]) -> list[npt.NDArray[np.intp]]:
    """Each frame's label permutation beyond the whole-body mirror (identity: no swap)."""
    out = []
    for o in observations:
        assert o.true_joints is not None
        base = MIRROR if o.mirrored else IDENTITY
        out.append(base[o.true_joints])  # the whole-body mirror is its own inverse
    return out


def test_single_limbs_swap_for_several_frames_in_side_views_only() -> None:
    params = replace(BARE, limb_swap_rate_hz=2.0, limb_swap_frames=(6, 20))
    allowed = [limb_swap(limb) for limb in SWAPPABLE_LIMBS]
    for yaw_deg, expect_swaps in ((90.0, True), (0.0, False), (180.0, False), (30.0, False)):
        body = facing(standing_pose(), math.radians(yaw_deg))
        extra = swapped_frames(watch(tracker(params), body, 900, 1 / 30))
        swapped = np.array([not np.array_equal(e, IDENTITY) for e in extra])
        if not expect_swaps:
            assert not swapped.any(), f"no limb swaps at {yaw_deg}°"
            continue
        assert 0.1 < swapped.mean() < 0.9, "2 swaps/s of 6–20 frames at 30 fps"
        for e in np.array(extra)[swapped]:
            assert any(np.array_equal(e, a) for a in allowed), "one arm or one leg, not more"
            moved = np.flatnonzero(e != IDENTITY)
            assert np.array_equal(e[moved], MIRROR[moved]), "left and right trade places"
            assert np.array_equal(np.sort(e), IDENTITY), "a permutation"
        starts = np.flatnonzero(np.diff(swapped.astype(int)) == 1) + 1
        ends = np.flatnonzero(np.diff(swapped.astype(int)) == -1) + 1
        runs = [end - start for start, end in zip(starts, ends[ends > starts[0]], strict=False)]
        assert runs and min(runs) >= 6


def test_a_swapped_limb_is_reported_where_the_other_limb_is() -> None:
    params = replace(BARE, limb_swap_rate_hz=5.0)
    body = facing(standing_pose(), math.radians(90.0))
    body[J.HAND_LEFT] += [0.0, 0.5, 0.0]  # tell the hands apart
    sensor = tracker(params)
    for o in watch(sensor, body, 300, 1 / 30):
        assert o.true_joints is not None
        world = apply(sensor.T_world_from_sensor, o.joints_m.astype(np.float64))
        # Each reported joint is where its true joint is (no noise, lean or bias here).
        assert np.allclose(world, body[o.true_joints], atol=1e-5)


def test_occluded_joints_are_inferred_and_pulled_towards_the_occluder() -> None:
    params = replace(BARE, occlusion_pull=0.6)
    back = standing_pose()
    front = standing_pose() + [0.0, 0.0, 1.0]  # between the sensor and the other person
    sensor = tracker(params, distance=3.5)
    seen = {o.person: o for o in sensor.observe(np.stack([back, front]), 0.0)}
    hidden = seen[0].states == TrackingState.INFERRED
    assert hidden[[J.SPINE_MID, J.SPINE_BASE]].all()
    assert (seen[1].states == TrackingState.TRACKED).mean() > 0.8
    true_sensor = apply(invert(sensor.T_world_from_sensor), back)[J.SPINE_MID]
    reported = seen[0].joints_m[J.SPINE_MID].astype(np.float64)
    front_surface = 3.5 - 1.0 - 0.13  # the front person's trunk capsule, its near side
    expected = 0.6 * (np.linalg.norm(true_sensor) - front_surface)
    moved = np.linalg.norm(true_sensor) - np.linalg.norm(reported)
    assert moved == pytest.approx(expected, rel=0.2), "pulled towards the sensor"
    lateral = np.linalg.norm(np.cross(reported, true_sensor / np.linalg.norm(true_sensor)))
    assert lateral < 0.01, "along its own sight line"


def test_seen_from_behind_the_whole_body_is_mirrored_and_says_so() -> None:
    body = facing(standing_pose(), math.pi)
    body[J.HAND_LEFT] += [0.0, 0.6, 0.0]
    sensor = tracker(BARE)
    observations = watch(sensor, body, 90, 1 / 30)
    assert np.mean([o.mirrored for o in observations]) > 0.95
    for o in observations:
        assert o.true_joints is not None
        assert np.array_equal(o.true_joints, MIRROR if o.mirrored else IDENTITY)
    o = next(o for o in observations if o.mirrored)
    world = apply(sensor.T_world_from_sensor, o.joints_m.astype(np.float64))
    assert np.linalg.norm(world[J.HAND_RIGHT] - body[J.HAND_LEFT]) < 0.02
    put_right = apply(sensor.T_world_from_sensor, o.labels_put_right().astype(np.float64))
    assert np.allclose(put_right, body, atol=1e-5)


def test_near_the_threshold_the_mirror_flickers_around_even_odds() -> None:
    params = replace(BARE, mirror_threshold_deg=115.0, mirror_width_deg=8.0, mirror_switch_hz=4.0)
    share = {}
    for yaw_deg in (115.0, 85.0):
        body = facing(standing_pose(), math.radians(yaw_deg))
        mirrored = np.array([o.mirrored for o in watch(tracker(params), body, 1500, 1 / 30)])
        share[yaw_deg] = float(mirrored.mean())
        if yaw_deg == 115.0:
            assert np.count_nonzero(np.diff(mirrored.astype(int))) >= 20, "it changes its mind"
    assert share[115.0] == pytest.approx(0.5, abs=0.15)  # ~200 independent stretches in 50 s
    assert share[85.0] < 0.05  # 30° = 3.75 widths short of the threshold: odds ≈ 2 %


def test_lean_grows_as_sin_times_abs_sin_saturates_and_is_asymmetric() -> None:
    params = DepthTrackerParams(lean_max_deg=30.0, lean_saturation_deg=60.0, lean_asymmetry=0.25)
    small, double = lean_turn(math.radians(10), params), lean_turn(math.radians(20), params)
    expected_ratio = (math.sin(math.radians(20)) / math.sin(math.radians(10))) ** 2
    assert double / small == pytest.approx(expected_ratio, rel=1e-9)
    assert math.degrees(lean_turn(math.radians(60), params)) == pytest.approx(30.0 * 1.25)
    assert lean_turn(math.radians(80), params) == lean_turn(math.radians(60), params)
    assert math.degrees(lean_turn(math.radians(-60), params)) == pytest.approx(-30.0 * 0.75)


def test_the_tracker_leans_the_reported_body_towards_the_sensor() -> None:
    params = replace(BARE, lean_max_deg=30.0, lean_saturation_deg=60.0, lean_asymmetry=0.0)
    body = facing(standing_pose(), math.radians(60.0))
    sensor = tracker(params)
    o = watch(sensor, body, 1, 1 / 30)[0]
    world = apply(sensor.T_world_from_sensor, o.joints_m.astype(np.float64))
    shoulders = world[J.SHOULDER_LEFT] - world[J.SHOULDER_RIGHT]
    reported = math.degrees(math.atan2(-shoulders[2], shoulders[0]))
    assert reported == pytest.approx(60.0 - 30.0, abs=1.0)


def test_same_seed_same_reports_other_seed_other_reports() -> None:
    body = facing(standing_pose(), math.radians(100.0))
    a, b, c = (tracker(DepthTrackerParams(), seed=s) for s in (5, 5, 6))
    differ = both = 0
    for i in range(60):
        oa, ob, oc = (s.observe(body[None], i / 30) for s in (a, b, c))
        assert len(oa) == len(ob)
        for x, y in zip(oa, ob, strict=True):
            np.testing.assert_array_equal(x.joints_m, y.joints_m)
            np.testing.assert_array_equal(x.states, y.states)
            assert np.array_equal(x.true_joints, y.true_joints)  # type: ignore[arg-type]
            assert x.tracking_id == y.tracking_id and x.mirrored == y.mirrored
        if oa and oc:
            both += 1
            differ += not np.allclose(oa[0].joints_m, oc[0].joints_m, equal_nan=True)
    assert both > 0 and differ == both, "another seed, other noise"
