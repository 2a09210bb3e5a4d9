"""Time offsets from motion (calibration/motion_sync.py): the simulator's routine seen by four
calibrated cameras with known lags, noise and gaps, and the real clip's cam03."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.calibration.errors import InvalidInput, NotEnoughCorrespondences
from skelfuse.calibration.motion_sync import lags_from_epipolar, lags_from_speed, shifted
from tests.unit.test_camera_triangulation import real_clip, rig

RATE_HZ = 60.0
LAGS = {"cam01": 0.0, "cam02": 1.4, "cam03": -3.0, "cam04": 2.6}


def performer_joints(lag_frames: float, frames: int, start_s: float) -> np.ndarray:
    """(frames, 25, 3) world joints of the simulator's routine as a camera lagging by
    ``lag_frames`` records them: its frame t shows the instant t - lag."""
    performer = ProceduralPerformer(1)
    times = start_s + (np.arange(frames) - lag_frames) / RATE_HZ
    return np.stack([performer.joints_at(float(t))[0] for t in times])


def recorded(frames: int = 150, noise_px: float = 1.5, seed: int = 0) -> np.ndarray:
    """(4, frames, 25, 2) pixels with noise, 10 % random gaps and a 20-frame dropout."""
    rng = np.random.default_rng(seed)
    views = []
    for camera in rig():
        joints = performer_joints(LAGS[camera.name], frames, start_s=3.0)
        views.append(camera.project(joints) + rng.normal(0.0, noise_px, (frames, 25, 2)))
    image = np.stack(views)
    image[rng.random(image.shape[:-1]) < 0.1] = np.nan
    image[2, 40:60] = np.nan  # cam03 lost the person for a third of a second
    return image


def test_epipolar_lags_of_synthetic_cameras_with_noise_and_gaps() -> None:
    sync = lags_from_epipolar(rig(), recorded(), rate_hz=RATE_HZ)
    for name, lag in LAGS.items():
        assert sync.lag_frames[name] == pytest.approx(lag, abs=0.25), (name, sync.lag_frames)
        assert sync.lag_s[name] == pytest.approx(sync.lag_frames[name] / RATE_HZ)
    assert min(sync.confidence.values()) > 0.5
    assert max(sync.cost.values()) < 5.0  # px: the noise, not a wrong alignment


def test_a_lag_beyond_the_search_range_has_no_confidence() -> None:
    sync = lags_from_epipolar(rig(), recorded(), rate_hz=RATE_HZ, max_lag_frames=2.0)
    assert sync.confidence["cam03"] == 0.0  # its -3 frames lie outside ±2


def test_speed_lags_of_the_same_body_in_metres() -> None:
    """Without calibration: the same joints, each source in its own frame (a rigid motion
    apart), lagged, with 5 mm of noise; body-size-normalised speeds are the same signal in
    every source. Weaker than the epipolar method: within a frame, not a quarter."""
    frames = 150
    rng = np.random.default_rng(4)
    tracks = []
    for k, lag in enumerate(LAGS.values()):
        joints = performer_joints(lag, frames, start_s=3.0)
        angle = 0.7 * k
        turn = np.array(
            [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
        )
        tracks.append(joints @ turn.T + rng.normal(0.0, 0.005, joints.shape))
    sync = lags_from_speed(np.stack(tracks), names=list(LAGS), rate_hz=RATE_HZ)
    for name, lag in LAGS.items():
        assert sync.lag_frames[name] == pytest.approx(lag, abs=1.0), (name, sync.lag_frames)


def test_refusals() -> None:
    cameras = rig()
    with pytest.raises(InvalidInput, match="at least 2 cameras"):
        lags_from_epipolar(cameras[:1], np.zeros((1, 10, 25, 2)), rate_hz=RATE_HZ)
    with pytest.raises(InvalidInput, match=r"\(V, T, J, 2\)"):
        lags_from_epipolar(cameras, np.zeros((4, 10, 2)), rate_hz=RATE_HZ)
    with pytest.raises(InvalidInput, match="positive"):
        lags_from_epipolar(cameras, recorded(frames=30), rate_hz=0.0)
    nobody = np.full((4, 30, 25, 2), np.nan)
    with pytest.raises(NotEnoughCorrespondences, match="cam01"):
        lags_from_epipolar(cameras, nobody, rate_hz=RATE_HZ)
    with pytest.raises(InvalidInput, match="one name per source"):
        lags_from_speed(np.zeros((2, 10, 25, 3)), names=["a"], rate_hz=RATE_HZ)


def test_real_clip_cam03_lags_two_to_three_frames() -> None:
    """The issue's real case: cam03 lags the others by 2-3 frames at 60 fps."""
    cameras, image = real_clip()
    sync = lags_from_epipolar(cameras, image, rate_hz=RATE_HZ, max_lag_frames=5.0)
    assert 2.0 <= sync.lag_frames["cam03"] <= 3.0, sync.lag_frames
    for name in ("cam02", "cam04"):
        assert abs(sync.lag_frames[name]) < 0.75, sync.lag_frames
    assert sync.confidence["cam03"] > 0.2
    # Speeds alone, without the calibration, do not pin these lags down (views too different,
    # too short a clip), and the estimate says so.
    speed = lags_from_speed(image[:, :, 11:29], names=[c.name for c in cameras], rate_hz=RATE_HZ)
    assert max(speed.confidence[c.name] for c in cameras[1:]) < 0.3, speed


def test_lags_need_the_motion_not_the_frame_index() -> None:
    """Sanity of the sign: rolling cam03's frames back by its lag leaves (almost) no lag."""
    cameras, image = real_clip({"cam03": 2})
    image[2, -2:] = np.nan  # the rolled-over frames
    sync = lags_from_epipolar(cameras, image, rate_hz=RATE_HZ, max_lag_frames=5.0)
    assert abs(sync.lag_frames["cam03"]) < 1.0, sync.lag_frames


def test_shifted_puts_a_lagging_track_on_the_reference_timeline() -> None:
    frames = 120
    reference = performer_joints(0.0, frames, start_s=5.0)
    lagging = performer_joints(2.5, frames, start_s=5.0)
    aligned = shifted(lagging, 2.5)
    assert np.isnan(aligned[-2:]).all() and np.isfinite(aligned[:-3]).all()
    error = np.linalg.norm(aligned[:-3] - reference[:-3], axis=-1)
    assert np.max(error) < 0.01  # metres: linear interpolation between 60 Hz frames
    assert np.max(np.linalg.norm(lagging[:-3] - reference[:-3], axis=-1)) > 0.03
