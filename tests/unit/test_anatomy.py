"""The body frame, joint angles, range-of-motion factors and facings against short plain-numpy
references written here, on simulated poses with noise, unknown joints and missing trunks."""

from __future__ import annotations

import numpy as np

from skelfuse.fusion import anatomy
from skelfuse.protocol.skeleton import JointId as J
from tests.support import random_views as _views


def _reference_frame(v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S, 3) up, left, forward: up SpineBase → SpineShoulder; left the finite hip and shoulder
    left-minus-right vectors summed, made normal to up; forward = left × up."""
    with np.errstate(invalid="ignore", divide="ignore"):
        up = anatomy.unit(v[:, J.SPINE_SHOULDER] - v[:, J.SPINE_BASE])
        hips = v[:, J.HIP_LEFT] - v[:, J.HIP_RIGHT]
        shoulders = v[:, J.SHOULDER_LEFT] - v[:, J.SHOULDER_RIGHT]
        lateral = np.nan_to_num(hips, nan=0.0) + np.nan_to_num(shoulders, nan=0.0)
        none = ~(np.isfinite(hips).all(1) | np.isfinite(shoulders).all(1))
        lateral[none] = np.nan
        left = anatomy.unit(lateral - (lateral * up).sum(1, keepdims=True) * up)
    return up, left, np.cross(left, up)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = (anatomy.unit(a) * anatomy.unit(b)).sum(-1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_the_angles_and_factors_follow_their_definitions() -> None:
    views = _views(0)
    up, left, forward = _reference_frame(views)
    factors, got_forward = anatomy.rom_factors_and_forward(views, 15.0)
    np.testing.assert_allclose(got_forward, forward, rtol=0, atol=1e-9)
    angles = anatomy.joint_angles(views)
    elbow = _angle(views[:, J.ELBOW_LEFT] - views[:, J.SHOULDER_LEFT],
                   views[:, J.WRIST_LEFT] - views[:, J.ELBOW_LEFT])  # fmt: skip
    np.testing.assert_allclose(angles["elbow_flexion_left"][0], elbow, atol=1e-9)
    neck = _angle(up, views[:, J.HEAD] - views[:, J.NECK])
    np.testing.assert_allclose(angles["neck_flexion"][0], neck, atol=1e-9)
    thigh = views[:, J.KNEE_RIGHT] - views[:, J.HIP_RIGHT]
    hip = np.degrees(np.arctan2((thigh * forward).sum(1), (thigh * -up).sum(1)))
    np.testing.assert_allclose(angles["hip_flexion_right"][0], hip, atol=1e-9)
    outwards = -(anatomy.unit(thigh) * left).sum(1)
    abduction = np.degrees(np.arcsin(np.clip(outwards, -1, 1)))
    np.testing.assert_allclose(angles["hip_abduction_right"][0], abduction, atol=1e-9)
    shank, foot = views[:, J.ANKLE_LEFT] - views[:, J.KNEE_LEFT], views[:, J.FOOT_LEFT] - views[
        :, J.ANKLE_LEFT]  # fmt: skip
    ankle = np.degrees(np.arctan2((np.cross(shank, foot) * -left).sum(1), (shank * foot).sum(1)))
    np.testing.assert_allclose(angles["ankle_shank_foot_left"][0], ankle, atol=1e-9)

    def factor(name: str, side: str) -> np.ndarray:
        low, high = anatomy.ROM_LIMITS_DEG[name]
        value = angles[f"{name}_{side}" if side else name][0]
        excess = np.maximum(low - value, 0.0) + np.maximum(value - high, 0.0)
        return np.where(np.isfinite(excess), np.exp(-excess / 15.0), 1.0)

    np.testing.assert_allclose(factors[:, J.WRIST_LEFT], factor("elbow_flexion", "left"), atol=1e-9)
    np.testing.assert_allclose(
        factors[:, J.FOOT_LEFT], factor("ankle_shank_foot", "left"), atol=1e-9
    )
    knee = factor("hip_flexion", "right") * factor("hip_abduction", "right")
    np.testing.assert_allclose(factors[:, J.KNEE_RIGHT], knee, atol=1e-9)
    np.testing.assert_allclose(factors[:, J.HEAD], factor("neck_flexion", ""), atol=1e-9)
    assert (factors[:, J.SPINE_BASE] == 1.0).all() and (factors < 0.5).any()
    assert np.isnan(got_forward).any() and np.isnan(elbow).any()  # unknown joints reached


def test_facings_are_the_forward_axis_made_horizontal() -> None:
    views = _views(1)
    _, _, forward = _reference_frame(views)
    horizontal = forward * [1.0, 0.0, 1.0]
    norm = np.linalg.norm(horizontal, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        expected = np.where(norm >= 1e-6, horizontal / norm, np.nan)
    got = anatomy.facing_directions(views)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    assert np.isnan(got).any() and np.isfinite(got).any()
    np.testing.assert_array_equal(anatomy.facing_direction(views[3]), got[3])
