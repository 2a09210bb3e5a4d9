"""Leave one camera out: fuse the other three live, judge them in the camera left out.

For each camera k: the other three stream to a real server (:func:`run_live`); the fused
person's twelve limb joints are projected into camera k (its calibration, with distortion)
and compared with camera k's own MediaPipe landmarks at the same instant (interpolated between
its frames, shifted by its lag): median pixel error and PCK at 0.2 × torso (camera k's
mid-shoulder to mid-hip, pixels, that frame). Every single camera j ≠ k is judged the same way:
streamed alone to a server of its own (``live``: the same filter and bone fit as the fused), and
its raw PnP placement without any server (``raw``). Target: fused beats every single camera by
≥ 30 % in median pixel error, for each k (issue 14).

Camera k never reaches the server of its own judgement: the fused joints cannot have seen it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.mono.geometry import FloatArray
from bench.mono.live import LiveRun, run_live
from bench.mono.metrics import (
    LIMB_JOINTS,
    LIMB_LANDMARKS,
    median,
    pck,
    pixel_errors,
    sample,
    torso_px,
)
from bench.mono.single import CAMERAS, Clip, single_camera
from skelfuse.calibration.camera import Camera

PCK_FRACTION = 0.2


@dataclass(frozen=True)
class Judged:
    """One prediction judged in one camera: median pixel error, PCK@0.2 torso, frames used."""

    median_px: float
    pck: float
    frames: int


def judge(points_world: FloatArray, positions: FloatArray, clip: Clip, cam: Camera, name: str,
          lag: float) -> Judged:  # fmt: skip
    """``points_world`` (N, 12, 3) limb joints at clip frames ``positions`` (N,) (the reference
    cameras' timeline) against camera ``name``'s landmarks there.

    Raises:
        ValueError: no frame with both the prediction and the camera's landmarks.
    """
    own = sample(clip.image_px[name][:, list(LIMB_LANDMARKS)], positions + lag)
    predicted = cam.project(points_world)
    errors = pixel_errors(predicted, own)
    ok = np.isfinite(errors).all(axis=1)
    if not ok.any():
        raise ValueError(f"no frame to judge in {name}")
    return Judged(median(errors[ok]), pck(errors[ok], torso_px(own[ok]), PCK_FRACTION),
                  int(ok.sum()))  # fmt: skip


def live_limbs(run: LiveRun) -> FloatArray:
    """The fused person's limb joints (F, 12, 3) from a live run."""
    return run.joints[:, list(LIMB_JOINTS)]


@dataclass
class LeaveOneOut:
    """Everything one leave-one-out round produced, per left-out camera."""

    fused: dict[str, Judged]
    single_live: dict[str, dict[str, Judged]]  # left out → single camera → judged
    single_raw: dict[str, dict[str, Judged]]
    runs: dict[str, LiveRun]  # "fused-<k>" or "single-<j>"


def leave_one_out(
    clip: Clip, cameras: dict[str, Camera], lags: dict[str, float], hold_s: float = 1.0
) -> LeaveOneOut:
    """Four fused runs (three cameras each) and four single-camera runs, judged everywhere."""
    runs: dict[str, LiveRun] = {}
    for k in CAMERAS:
        runs[f"fused-{k}"] = run_live(clip, cameras, tuple(c for c in CAMERAS if c != k), lags,
                                      hold_s=hold_s)  # fmt: skip
    for j in CAMERAS:
        runs[f"single-{j}"] = run_live(clip, cameras, (j,), lags, hold_s=hold_s)
    # Raw placements on the reference timeline: camera j's frame i shows clip frame i − lag_j.
    raw = {j: single_camera(clip, cameras[j], j)[:, list(LIMB_LANDMARKS)] for j in CAMERAS}
    result = LeaveOneOut({}, {}, {}, runs)
    for k in CAMERAS:
        cam, lag = cameras[k], lags.get(k, 0.0)
        fused = runs[f"fused-{k}"]
        result.fused[k] = judge(live_limbs(fused), fused.times, clip, cam, k, lag)
        result.single_live[k], result.single_raw[k] = {}, {}
        for j in CAMERAS:
            if j == k:
                continue
            single = runs[f"single-{j}"]
            result.single_live[k][j] = judge(live_limbs(single), single.times, clip, cam, k, lag)
            frames = np.arange(len(raw[j]), dtype=np.float64) - lags.get(j, 0.0)
            result.single_raw[k][j] = judge(raw[j], frames, clip, cam, k, lag)
    return result
