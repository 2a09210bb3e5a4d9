"""Why fused three cameras do or do not beat one: the leave-one-out judgement of fusions made
offline, without the server, from the same three single-camera placements.

For each camera k left out, judged in k as ``bench/mono/loo.py`` does (median pixel
error of the twelve limb joints):

- each single camera j ≠ k (its raw PnP placement), with the angle between j's and k's optical
  axes: a camera j facing k (angle near 180°) has its depth error along k's own line of sight,
  where k cannot see it, so it looks better in k than it is;
- the plain mean of the three (what fusion does when every direction counts the same);
- the product's ray-weighted mean (:func:`skelfuse.fusion.view_factors.ray_weighted_mean`,
  equal weights) at several depth-noise ratios; the ``rgb`` prior's is
  ``fusion/priors.py``'s ``depth_noise_ratio``;
- the three views' 2-D landmarks triangulated (no single-camera depth at all): how far fusing
  the three could go with these landmarks.

No filter, no association, no mirror step, no bone fit: differences between this and the live
table are the live pipeline's.
"""

from __future__ import annotations

import numpy as np

from bench.mono.geometry import FloatArray
from bench.mono.loo import judge
from bench.mono.metrics import LIMB_LANDMARKS
from bench.mono.single import CAMERAS, Clip, reference, single_camera
from skelfuse.calibration.camera import Camera
from skelfuse.fusion.view_factors import ray_weighted_mean

RATIOS = (1.0, 3.0, 5.0, 10.0)


def axis_angle_deg(a: Camera, b: Camera) -> float:
    """Angle between two cameras' optical axes (+Z of the sensor frame), degrees."""
    za, zb = a.T_world_from_sensor[:3, 2], b.T_world_from_sensor[:3, 2]
    return float(np.degrees(np.arccos(np.clip(za @ zb, -1.0, 1.0))))


def ray_fused(points: list[FloatArray], centres: list[FloatArray], ratio: float) -> FloatArray:
    """Views (T, J, 3) from cameras at ``centres`` (3,) fused by the product's ray weighting."""
    joints = np.stack(points, axis=1)  # (T, S, J, 3): frames as fusion's persons
    t, s = joints.shape[:2]
    weights = np.where(np.isfinite(joints).all(axis=-1), 1.0, 0.0)
    sensors = np.broadcast_to(np.stack(centres), (t, s, 3)).copy()
    return ray_weighted_mean(joints, weights, sensors, np.full((t, s), ratio))


def diagnose(
    clip: Clip, cameras: dict[str, Camera], lags: dict[str, float]
) -> dict[str, dict[str, float]]:
    """Per left-out camera: label → median pixel error in it (angles under ``angle <j>``)."""
    aligned = clip.shifted(lags)  # every camera on cam01's timeline
    limbs = list(LIMB_LANDMARKS)
    raw = {j: single_camera(aligned, cameras[j], j)[:, limbs] for j in CAMERAS}
    centres = {j: cameras[j].T_world_from_sensor[:3, 3] for j in CAMERAS}
    frames = np.arange(len(raw[CAMERAS[0]]), dtype=np.float64)
    rows: dict[str, dict[str, float]] = {}
    for k in CAMERAS:
        cam = cameras[k]
        others = [j for j in CAMERAS if j != k]
        row: dict[str, float] = {}
        for j in others:
            row[j] = judge(raw[j], frames, aligned, cam, k, 0.0).median_px
            row[f"angle {j}"] = axis_angle_deg(cameras[j], cam)
        views = [raw[j] for j in others]
        row["mean"] = judge(
            np.nanmean(np.stack(views), axis=0), frames, aligned, cam, k, 0.0
        ).median_px
        for ratio in RATIOS:
            fused = ray_fused(views, [centres[j] for j in others], ratio)
            row[f"ray {ratio:g}"] = judge(fused, frames, aligned, cam, k, 0.0).median_px
        tri = reference(aligned, cameras, tuple(others))[:, limbs]
        row["triangulated"] = judge(tri, frames, aligned, cam, k, 0.0).median_px
        rows[k] = row
    return rows


def print_diagnosis(rows: dict[str, dict[str, float]]) -> None:
    """The table: singles with their axis angle to k, then the offline fusions."""
    print("\noffline fusions judged in the camera left out (median px; no server):")
    ratios = " | ".join(f"ray-weighted {r:g}" for r in RATIOS)
    print(f"| left out | singles (axis angle to it) | best single | mean of three | {ratios} "
          "| triangulated three |")  # fmt: skip
    print("|---" * (5 + len(RATIOS)) + "|")
    for k, row in rows.items():
        others = [j for j in CAMERAS if j != k]
        singles = ", ".join(f"{j} {row[j]:.1f} ({row[f'angle {j}']:.0f}°)" for j in others)
        best = min(row[j] for j in others)
        fused = " | ".join(
            f"{row[f'ray {r:g}']:.1f} ({100 * (1 - row[f'ray {r:g}'] / best):+.0f} %)"
            for r in RATIOS
        )
        tri = row["triangulated"]
        print(f"| {k} | {singles} | {best:.1f} | {row['mean']:.1f} "
              f"({100 * (1 - row['mean'] / best):+.0f} %) | {fused} "
              f"| {tri:.1f} ({100 * (1 - tri / best):+.0f} %) |")  # fmt: skip
