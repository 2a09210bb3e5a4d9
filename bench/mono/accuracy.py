"""Accuracy of one ordinary camera, and of three fused, on the real four-camera clip (issue 14).

Data, all in the repository: the MediaPipe landmark fixture ``tests/data/mono_landmarks.npz``
(100 frames at 60 fps per camera of ``../shared/data/pose2sim-single``) and the clip's Qualisys
calibration ``tests/data/pose2sim_single_calib.qca.txt``. Figures:

1. single camera against the four-view reference (``bench/mono/single.py``): MPJPE
   absolute, root-aligned, Procrustes-aligned on the twelve limb joints, in mm;
2. leave one camera out (``bench/mono/loo.py``): the other three fused live through a
   real server on loopback, projected into the camera left out: median pixel error and PCK at
   0.2 torso, against every single camera judged the same way.

cam03 lags the others: every camera's lag (frames) comes from the product's motion sync
(``calibration/motion_sync.py``, epipolar distances; ``--lag cam03=L`` overrides one), checked
against the shift that minimises the four-view triangulation's reprojection error.

3. why (``bench/mono/diagnose.py``): the same judgement of fusions made offline from
   the same single-camera placements (plain mean, the product's ray weighting at several depth
   noise ratios, the three views triangulated), and the angles between the cameras' axes.

Run: ``python -m bench mono_accuracy`` (``--single``, ``--diagnose`` or ``--loo`` for one part,
``--json FILE`` raw results, ``--hold-s`` the still lead-in before the clip plays,
``--fusion-config FILE`` other fusion settings for the live servers).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from bench.mono.diagnose import diagnose, print_diagnosis
from bench.mono.geometry import load_cameras
from bench.mono.loo import leave_one_out
from bench.mono.single import (
    CALIBRATION,
    CAMERAS,
    FIXTURE,
    Clip,
    lag_by_reprojection,
    load_clip,
    motion_sync_lags,
    reference,
    reprojection_px,
    single_vs_reference,
)
from skelfuse.calibration.camera import Camera

ROOT_TARGET_MM = 150.0
PROCRUSTES_TARGET_MM = 80.0
GAIN_TARGET = 0.30


def parse_lags(items: list[str]) -> dict[str, float]:
    """``cam03=2.5`` items → {camera: frames}.

    Raises:
        ValueError: an item is not ``camera=number`` or names no camera of the clip.
    """
    lags: dict[str, float] = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in CAMERAS:
            raise ValueError(f"--lag {item!r}: camera must be one of {', '.join(CAMERAS)}")
        lags[name] = float(value)
    return lags


def main(argv: list[str] | None = None) -> int:
    """Parse the command line, run the parts asked for, print markdown tables; exit status."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--single", action="store_true", help="only the single-camera part")
    parser.add_argument("--loo", action="store_true", help="only the leave-one-out part")
    parser.add_argument("--diagnose", action="store_true",
                        help="only the offline fusions (mono/diagnose.py)")  # fmt: skip
    parser.add_argument("--lag", action="append", default=[], help="CAMERA=FRAMES, e.g. cam03=2.5")
    parser.add_argument("--hold-s", type=float, default=1.0, help="still lead-in, seconds")
    parser.add_argument("--json", type=Path, default=None, help="write raw results here")
    parser.add_argument("--fusion-config", type=Path, default=None,
                        help="TOML [fusion] table for the live servers, e.g. "
                             "use_mirror_correction = false")  # fmt: skip
    parser.add_argument("--fixture", type=Path, default=FIXTURE)
    parser.add_argument("--calibration", type=Path, default=CALIBRATION)
    args = parser.parse_args(argv)
    if not args.calibration.is_file():
        print(f"calibration not found: {args.calibration}", file=sys.stderr)
        return 2
    if args.fusion_config:  # bench/live/server.py hands it to every server it starts
        os.environ["SKELFUSE_LOAD_FUSION_CONFIG"] = str(args.fusion_config.resolve())
    clip, cameras = load_clip(args.fixture), load_cameras(args.calibration)
    found = motion_sync_lags(clip, cameras)
    check = lag_by_reprojection(clip, cameras, "cam03", np.arange(0.0, 5.01, 0.25))
    print("lags behind cam01 from the motion sync (frames): "
          + ", ".join(f"{c} {v:+.2f}" for c, v in found.items())
          + f"; cam03 by the triangulation's reprojection error: {check:+.2f}")  # fmt: skip
    lags = {**found, **parse_lags(args.lag)}
    print("lags used: " + ", ".join(f"{c} {v:+.2f}" for c, v in lags.items()))
    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    out: dict[str, object] = {"lags": lags}
    everything = not (args.single or args.loo or args.diagnose)
    if args.single or everything:
        out["single"] = print_single(clip, cameras, lags)
    if args.diagnose or everything:
        out["diagnose"] = diagnosis = diagnose(clip, cameras, lags)
        print_diagnosis(diagnosis)
    if args.loo or everything:
        out["loo"] = print_loo(clip, cameras, lags, args.hold_s)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


def print_single(
    clip: Clip, cameras: dict[str, Camera], lags: dict[str, float]
) -> dict[str, dict[str, float]]:
    """Part 1's table; returns its rows."""
    aligned = clip.shifted(lags)
    ref = reference(aligned, cameras)
    print(f"\nreference: four views triangulated, median reprojection "
          f"{reprojection_px(ref, aligned, cameras):.1f} px on the limb joints")  # fmt: skip
    rows = single_vs_reference(aligned, cameras, ref)
    print("\n| camera | frames | absolute mean / median | root-aligned mean / median "
          "| Procrustes mean / median |")  # fmt: skip
    print("|---|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['frames']:.0f} | {r['abs_mean']:.0f} / {r['abs_median']:.0f} "
              f"| {r['root_mean']:.0f} / {r['root_median']:.0f} "
              f"| {r['procrustes_mean']:.0f} / {r['procrustes_median']:.0f} |")  # fmt: skip
    worst_root = max(r["root_mean"] for r in rows.values())
    worst_pa = max(r["procrustes_mean"] for r in rows.values())
    print(f"\nworst camera: root-aligned {worst_root:.0f} mm (target ≤ {ROOT_TARGET_MM:.0f}: "
          f"{'met' if worst_root <= ROOT_TARGET_MM else 'MISSED'}), Procrustes {worst_pa:.0f} mm "
          f"(target ≤ {PROCRUSTES_TARGET_MM:.0f}: "
          f"{'met' if worst_pa <= PROCRUSTES_TARGET_MM else 'MISSED'})")  # fmt: skip
    return rows


def print_loo(
    clip: Clip, cameras: dict[str, Camera], lags: dict[str, float], hold_s: float
) -> dict[str, object]:
    """Part 2's table; returns its rows."""
    started = time.perf_counter()
    result = leave_one_out(clip, cameras, lags, hold_s)
    print(f"\nleave one out: 8 live runs in {time.perf_counter() - started:.0f} s")
    print("\n| left out | fused three: median px / PCK@0.2 | single (live): median px / PCK "
          "| single (raw PnP): median px / PCK | fused vs best single (live) |")  # fmt: skip
    print("|---|---|---|---|---|")
    rows: dict[str, object] = {}
    for k in CAMERAS:
        fused = result.fused[k]
        live = result.single_live[k]
        raw = result.single_raw[k]
        best = min(j.median_px for j in live.values())
        gain = 1.0 - fused.median_px / best
        cells_live = ", ".join(f"{j} {v.median_px:.1f} / {v.pck:.2f}" for j, v in live.items())
        cells_raw = ", ".join(f"{j} {v.median_px:.1f} / {v.pck:.2f}" for j, v in raw.items())
        verdict = "met" if gain >= GAIN_TARGET else "MISSED"
        print(f"| {k} | {fused.median_px:.1f} / {fused.pck:.2f} ({fused.frames} frames) "
              f"| {cells_live} | {cells_raw} | {100 * gain:+.0f} % ({verdict}) |")  # fmt: skip
        rows[k] = {"fused": asdict(fused), "single_live": {j: asdict(v) for j, v in live.items()},
                   "single_raw": {j: asdict(v) for j, v in raw.items()}, "gain": gain}  # fmt: skip
    print("\nlive runs (persons published per frame; sensors the mirror step swapped, frames):")
    for label, run in result.runs.items():
        print(f"  {label}: {len(run.times)} fused frames, persons {run.persons.mean():.2f}, "
              f"mirrored {run.mirrored or 'none'}")  # fmt: skip
    return rows
