"""Fusion with noise stretched along a camera's viewing ray (fusion/view_factors.py) and its
use by the view batch for ``rgb`` views (fusion/weigh.py)."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion.priors import RGB_MONO
from skelfuse.fusion.view_factors import depth_noise_ratios, ray_weighted_mean
from skelfuse.fusion.views import View
from skelfuse.fusion.weigh import ViewBatch, weighted_mean
from skelfuse.protocol.skeleton import JOINT_COUNT

TRUTH = np.array([0.0, 1.0, 3.0])
CAMERA = np.array([0.0, 1.0, 0.0])  # looks along +Z at the joint
KINECT = np.array([3.0, 1.0, 3.0])  # looks along −X at it


def _two_views() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One joint: the camera 0.3 m too far (depth), the Kinect 0.05 m off along its own ray."""
    joints = np.array([[[TRUTH + [0.0, 0.0, 0.3]], [TRUTH + [0.05, 0.0, 0.0]]]])  # (1, 2, 1, 3)
    weights = np.ones((1, 2, 1))
    sensors = np.array([[CAMERA, KINECT]])
    return joints, weights, sensors


def test_a_second_view_fixes_the_cameras_depth_and_the_camera_keeps_its_side() -> None:
    joints, weights, sensors = _two_views()
    plain = weighted_mean(joints, weights)[0, 0]
    np.testing.assert_allclose(plain, TRUTH + [0.025, 0.0, 0.15])
    fused = ray_weighted_mean(joints, weights, sensors, np.array([[3.0, 1.0]]))[0, 0]
    # Depth (z) mostly the Kinect's, x mostly the camera's: (1/9·0.3 + 0) / (1/9 + 1) = 0.03.
    np.testing.assert_allclose(fused, TRUTH + [0.025, 0.0, 0.03], atol=1e-12)
    both = ray_weighted_mean(joints, weights, sensors, np.array([[3.0, 3.0]]))[0, 0]
    np.testing.assert_allclose(both, TRUTH + [0.005, 0.0, 0.03], atol=1e-12)


def test_ratio_one_is_the_weighted_mean_and_one_view_is_itself() -> None:
    rng = np.random.default_rng(4)
    joints = rng.normal(0.0, 1.0, (3, 4, JOINT_COUNT, 3))
    joints[rng.random((3, 4, JOINT_COUNT)) < 0.2] = np.nan
    weights = rng.random((3, 4, JOINT_COUNT))
    weights[:, 3] = 0.0
    sensors = rng.normal(0.0, 3.0, (3, 4, 3))
    ones = np.ones((3, 4))
    np.testing.assert_allclose(
        ray_weighted_mean(joints, weights, sensors, ones), weighted_mean(joints, weights),
        rtol=1e-12, atol=1e-12,
    )  # fmt: skip
    ratios = ones.copy()
    ratios[1] = 3.0
    alone = ray_weighted_mean(joints[:, :1], weights[:, :1], sensors[:, :1], ratios[:, :1])
    np.testing.assert_allclose(alone, weighted_mean(joints[:, :1], weights[:, :1]), atol=1e-12)
    # Persons without a ratio other than 1 keep the given plain mean's bits.
    plain = weighted_mean(joints, weights)
    mixed = ray_weighted_mean(joints, weights, sensors, ratios, plain)
    assert np.array_equal(mixed[[0, 2]], plain[[0, 2]], equal_nan=True)
    assert not np.allclose(mixed[1], plain[1], equal_nan=True)
    with pytest.raises(ValueError, match=">= 1"):
        ray_weighted_mean(joints, weights, sensors, ones * 0.5)


def test_unknown_sensor_positions_count_as_isotropic() -> None:
    joints, weights, sensors = _two_views()
    sensors[0, 0] = np.nan
    fused = ray_weighted_mean(joints, weights, sensors, np.array([[3.0, 1.0]]))
    np.testing.assert_allclose(fused, weighted_mean(joints, weights), atol=1e-12)


def test_the_view_batch_stretches_rgb_views_only() -> None:
    assert depth_noise_ratios(["kinect_v2", "sim", "azure_kinect", "unknown"]) is None
    np.testing.assert_array_equal(
        depth_noise_ratios(["kinect_v2", "rgb"]), [1.0, RGB_MONO.depth_noise_ratio]
    )
    body = np.tile(TRUTH, (JOINT_COUNT, 1))
    states = np.full(JOINT_COUNT, 2, np.uint8)
    camera = View("cam", 1, body + [0.0, 0.0, 0.3], states, CAMERA, sensor_type="rgb")
    kinect = View("k", 1, body + [0.05, 0.0, 0.0], states, KINECT, sensor_type="kinect_v2")
    weights = np.ones((2, JOINT_COUNT))
    batch = ViewBatch.of([[camera, kinect]])
    r = RGB_MONO.depth_noise_ratio
    fused = batch.fuse(weights)[0]
    # A weight is a 3-D precision: across its ray the camera's is (2 + r²) / 3 times more.
    across = (2 + r**2) / 3
    along = across / r**2
    np.testing.assert_allclose(fused[:, 2], TRUTH[2] + 0.3 * along / (along + 1), atol=1e-12)
    np.testing.assert_allclose(fused[:, 0], 0.05 / (across + 1), atol=1e-12)
    kinects = ViewBatch.of([[View("k2", 1, camera.joints_world, states, CAMERA), kinect]])
    assert kinects.depth_ratios is None
    assert np.array_equal(
        kinects.fuse(weights), weighted_mean(kinects.pad(kinects.joints, np.nan), weights[None])
    )


def test_without_sensor_priors_rgb_views_are_isotropic() -> None:
    states = np.full(JOINT_COUNT, 2, np.uint8)
    body = np.tile(TRUTH, (JOINT_COUNT, 1))
    camera = View("cam", 1, body + [0.0, 0.0, 0.3], states, CAMERA, sensor_type="rgb")
    kinect = View("k", 1, body + [0.05, 0.0, 0.0], states, KINECT)
    batch = ViewBatch.of([[camera, kinect]], depth_noise=False)
    assert batch.depth_ratios is None
    np.testing.assert_allclose(batch.fuse(np.ones((2, JOINT_COUNT)))[0, 0], TRUE_MEAN)


TRUE_MEAN = TRUTH + [0.025, 0.0, 0.15]
