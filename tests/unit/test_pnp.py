"""Pinhole intrinsics and perspective-n-point in numpy (geometry/pinhole.py, geometry/pnp.py)."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.geometry.pinhole import CV_TO_SENSOR, Intrinsics
from skelfuse.geometry.pnp import PnPError, rotation_vector_to_matrix, solve_pose, solve_translation

K = Intrinsics(1400.0, 1390.0, 540.0, 960.0)


def _body(seed: int = 0) -> np.ndarray:
    """33 points spread like a standing body (metres, hip-centred, camera axes)."""
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, [0.2, 0.5, 0.12], size=(33, 3))


def test_intrinsics_parse_fov_and_matrix() -> None:
    assert Intrinsics.parse(" 1400, 1390,540 ,960") == K
    for bad in ("1,2,3", "a,b,c,d", "0,1,2,3", "1,1,nan,3"):
        with pytest.raises(ValueError, match=r"intrinsics|fx,fy"):
            Intrinsics.parse(bad)
    guess = Intrinsics.from_fov(1920, 1080, 90.0)
    assert guess.fx == pytest.approx(960.0) and (guess.cx, guess.cy) == (960.0, 540.0)
    with pytest.raises(ValueError, match="field of view"):
        Intrinsics.from_fov(1920, 1080, 180.0)
    assert K.matrix()[0, 0] == 1400.0 and K.matrix()[1, 2] == 960.0
    np.testing.assert_array_equal(CV_TO_SENSOR * CV_TO_SENSOR, np.ones(3))


def test_project_and_rays_agree() -> None:
    points = _body() + [0.1, -0.2, 3.0]
    pixels = K.project(points)
    rays = K.rays(pixels)
    np.testing.assert_allclose(rays, points / np.linalg.norm(points, axis=1, keepdims=True))


def test_pose_recovers_an_exact_placement() -> None:
    model = _body(1)
    rotation = rotation_vector_to_matrix([0.1, -0.25, 0.05])
    t = np.array([0.3, -0.4, 2.7])
    pixels = K.project(model @ rotation.T + t)
    placement = solve_pose(model, pixels, K)
    np.testing.assert_allclose(placement.rotation, rotation, atol=1e-9)
    np.testing.assert_allclose(placement.translation, t, atol=1e-9)
    assert placement.rms_px < 1e-6
    np.testing.assert_allclose(placement.apply(model), model @ rotation.T + t, atol=1e-9)


def test_translation_recovers_an_exact_translation() -> None:
    model = _body(2)
    t = np.array([-0.5, 0.2, 4.0])
    placement = solve_translation(model, K.project(model + t), K)
    np.testing.assert_allclose(placement.translation, t, atol=1e-9)
    np.testing.assert_array_equal(placement.rotation, np.eye(3))


def test_zero_weight_drops_a_wild_point_and_nan_points_are_skipped() -> None:
    model = _body(3)
    t = np.array([0.0, 0.0, 3.0])
    pixels = K.project(model + t)
    pixels[5] += 400.0  # one landmark far off
    pixels[6] = np.nan
    weights = np.ones(33)
    weights[5] = 0.0
    np.testing.assert_allclose(solve_pose(model, pixels, K, weights).translation, t, atol=1e-9)
    assert np.abs(solve_pose(model, pixels, K).translation - t).max() > 1e-3


def test_rotation_vector_matches_a_known_turn() -> None:
    quarter = rotation_vector_to_matrix([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(quarter @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(rotation_vector_to_matrix([0.0, 0.0, 0.0]), np.eye(3))


def test_unsolvable_inputs_raise() -> None:
    model = _body(4)
    pixels = K.project(model + [0.0, 0.0, 3.0])
    with pytest.raises(PnPError, match="usable points"):
        solve_pose(model[:3], pixels[:3], K)
    with pytest.raises(PnPError, match="usable points"):
        solve_translation(model, pixels, K, np.zeros(33))
    with pytest.raises(ValueError, match="expected model"):
        solve_pose(model, pixels[:, :1], K)
    with pytest.raises(PnPError, match="in front of the camera"):
        solve_pose(
            model,
            pixels,
            K,
            initial=solve_pose(model, pixels, K).__class__(
                np.eye(3), np.array([0.0, 0.0, -3.0]), 0.0, 0
            ),
        )
