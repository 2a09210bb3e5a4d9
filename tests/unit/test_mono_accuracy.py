"""The mono accuracy benchmark's metrics on inputs whose answers are known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from bench.mono.loo import judge
from bench.mono.metrics import (
    LIMB_LANDMARKS,
    median,
    mpjpe,
    pck,
    pixel_errors,
    procrustes_aligned,
    root_aligned,
    sample,
    shifted,
    torso_px,
)
from bench.mono.single import Clip
from skelfuse.calibration.camera import Camera, CameraIntrinsics


def limbs(seed: int = 0, frames: int = 3) -> np.ndarray:
    """(frames, 12, 3) points a body's size apart, metres."""
    return np.random.default_rng(seed).normal(0.0, 0.4, (frames, 12, 3)) + [0.0, 1.0, 3.0]


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_mpjpe_and_root_alignment() -> None:
    ref = limbs()
    moved = ref + [0.03, 0.04, 0.0]  # 5 cm everywhere
    assert np.allclose(mpjpe(moved, ref), 0.05)
    assert np.allclose(root_aligned(moved, ref), 0.0, atol=1e-12)
    bent = ref.copy()
    bent[:, 4] += [0.0, 0.1, 0.0]  # one wrist 10 cm off; the root (hips 6, 7) stays
    errors = root_aligned(bent, ref)
    assert np.isclose(errors[:, 4], 0.1).all() and np.isclose(np.delete(errors, 4, 1), 0).all()


def test_procrustes_removes_a_similarity_but_not_a_mirror_or_a_pose_change() -> None:
    ref = limbs(1)
    similar = 1.3 * ref @ rotation_z(0.7).T + [1.0, -2.0, 0.5]
    assert np.allclose(procrustes_aligned(similar, ref), 0.0, atol=1e-9)
    mirrored = ref * [-1.0, 1.0, 1.0]
    assert procrustes_aligned(mirrored, ref).mean() > 0.05
    bent = ref.copy()
    bent[:, 4] += [0.2, 0.0, 0.0]  # 20 cm: alignment spreads some of it over the rest
    assert 0.0 < procrustes_aligned(bent, ref)[:, 4].mean() < 0.2


def test_procrustes_leaves_missing_joints_out() -> None:
    ref = limbs(2)
    pred = ref + [0.1, 0.0, 0.0]
    pred[0, 3] = np.nan
    errors = procrustes_aligned(pred, ref)
    assert np.isnan(errors[0, 3]) and np.allclose(np.delete(errors[0], 3), 0.0, atol=1e-9)


def test_torso_pck_and_median() -> None:
    own = np.zeros((2, 12, 2))
    own[:, (0, 1)] = [0.0, 0.0]  # shoulders
    own[:, (6, 7)] = [0.0, 100.0]  # hips: torso 100 px
    assert np.allclose(torso_px(own), 100.0)
    errors = np.full((2, 12), 10.0)
    errors[1] = 25.0  # beyond 0.2 × 100
    errors[0, 0] = np.nan  # not judged
    assert pck(errors, torso_px(own)) == pytest.approx(11 / 23)
    assert pck(errors, torso_px(own), fraction=0.3) == 1.0
    assert median(errors) == 25.0
    with pytest.raises(ValueError, match="no finite errors"):
        pck(np.full((1, 12), np.nan), np.array([100.0]))
    assert np.allclose(pixel_errors(np.zeros((1, 1, 2)), np.array([[[3.0, 4.0]]])), 5.0)


def test_sample_and_shift_interpolate_and_leave_the_clip_nan() -> None:
    track = np.arange(5.0)[:, None] * [1.0, 10.0]
    assert np.allclose(sample(track, np.array([0.5, 3.25]))[:, 1], [5.0, 32.5])
    assert np.isnan(sample(track, np.array([-0.1, 4.1]))).all()
    lagged = shifted(track, 2.0)  # frame i of a camera 2 frames late shows frame i + 2
    assert np.allclose(lagged[:3, 0], [2.0, 3.0, 4.0]) and np.isnan(lagged[3:]).all()


def test_judge_is_zero_on_the_cameras_own_points_and_grows_with_an_offset() -> None:
    camera = Camera("cam", CameraIntrinsics(1000, 1000, 800.0, 800.0, 500.0, 500.0, ()), np.eye(4))
    points = limbs(3, frames=4)  # in front of the camera (z ≈ 3 m)
    image = np.full((4, 33, 2), np.nan)
    image[:, list(LIMB_LANDMARKS)] = camera.project(points)
    clip = Clip({"cam": image}, {}, {})
    frames = np.arange(4.0)
    exact = judge(points, frames, clip, camera, "cam", 0.0)
    assert exact.median_px == pytest.approx(0.0, abs=1e-6) and exact.pck == 1.0
    assert exact.frames == 4
    # 5 cm sideways at 3 m: about 800 × 0.05 / 3 ≈ 13 px.
    off = judge(points + [0.05, 0.0, 0.0], frames, clip, camera, "cam", 0.0)
    assert 10.0 < off.median_px < 17.0
    late = judge(points, frames - 1.0, clip, camera, "cam", 1.0)  # the lag undoes the shift
    assert late.median_px == pytest.approx(0.0, abs=1e-6)
