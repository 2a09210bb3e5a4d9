"""Depth re-projection into the level reference camera on simulated depth (issue 15 item 4).

    .venv/bin/python -m bench reprojection

A person (:func:`agent.sim.performer.standing_pose`) in the default room, seen by a
head-mounted Kinect v2-like camera 1.6 m up and ~2 m away, pitched and/or rolled about a neck
pivot 8 cm behind and below it (parallax). Each frame is rendered by the simulator's ray caster
(:func:`agent.sim.room.render_depth`), ideal and with its noise model (σ 1.5 mm + 1.5 mm·z²,
2 % dropout, flying pixels removed), re-projected with :func:`agent.reproject.reproject_depth`
and compared with the ideal render of the level reference camera itself:

- holes: the reference's person silhouette (where the person changes its depth by > 5 cm)
  within the sensor's view without a reading, in %, for points alone (``max_edge_m=0``) and
  mesh plus points; beside it, the holes of a noisy level camera (the input's own dropout and rim);
- error: median |depth − truth| over the silhouette pixels seen, mm;
- hard edges: the ideal render with the SDK's flying-pixel removal and the grazing-angle loss
  off (person and background then share edges, so the mesh can bridge them);
- ghosts: pixels (% of the image) more than 10 cm nearer than the truth, with the 10 cm edge
  rule and without it (the mesh then bridges person and background);
- time: median of 20 calls on a 512×424 depth + IR frame (uint16), numba loop (one thread)
  and the numpy twin, with the load average. Geometry figures do not depend on the load.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import numpy.typing as npt

from skelfuse.agent.reproject import level_reference, reference_from_sensor, reproject_depth
from skelfuse.agent.sim.depth_camera import (
    KINECT_V2_DEPTH,
    DepthNoise,
    pixel_rays,
)
from skelfuse.agent.sim.performer import standing_pose
from skelfuse.agent.sim.room import default_room, render_depth
from skelfuse.protocol.transform import (
    apply,
    invert,
    pose_from_position_yaw_pitch,
)

FloatArray = npt.NDArray[np.float64]
CASES = ((20.0, 0.0), (0.0, 20.0), (20.0, 20.0), (-20.0, 20.0), (10.0, -10.0))
"""(pitch, roll) in degrees."""


def _rotation(axis: int, deg: float) -> FloatArray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    i, j = [k for k in range(3) if k != axis]
    out = np.eye(4)
    out[i, i], out[i, j], out[j, i], out[j, j] = c, -s, s, c
    return out


def head_pose(pitch_deg: float, roll_deg: float) -> FloatArray:
    """The sensor's pose: heading 10°, pitch and roll about a neck pivot 8 cm back and down."""
    neck = pose_from_position_yaw_pitch((0.0, 1.52, -2.08), 10.0)
    lever = np.eye(4)
    lever[:3, 3] = (0.0, 0.08, 0.08)
    return neck @ _rotation(0, pitch_deg) @ _rotation(2, roll_deg) @ lever


def case_figures(pitch_deg: float, roll_deg: float, seed: int) -> dict[str, float]:
    """Holes (%), median error (mm) and ghosts (% of image) of one head pose."""
    room, person = default_room(), standing_pose()[None]
    pose = head_pose(pitch_deg, roll_deg)
    # The reference is the untilted head (the prototype's 8 cm of parallax from the neck
    # pivot); level_reference(pose) itself sits at the sensor: no parallax, no disocclusion.
    ref = level_reference(head_pose(0.0, 0.0))
    transform = invert(ref) @ pose
    truth = render_depth(room, person, ref).astype(np.float64)
    silhouette = (np.abs(truth - render_depth(room, None, ref)) > 0.05) & (truth > 0)
    silhouette &= in_sensor_view(truth, transform)
    own = render_depth(room, person, ref, rng=np.random.default_rng(seed + 1))
    figures = {"own holes %": 100.0 * float((silhouette & (own == 0)).sum() / silhouette.sum())}
    hard = DepthNoise(edge_jump_fraction=np.inf, max_incidence_deg=90.0)
    inputs = (("ideal", None, None), ("noisy", np.random.default_rng(seed), None))
    for label, rng, model in (*inputs, ("hard edges", None, hard)):
        depth = render_depth(room, person, pose, rng=rng, noise=model).astype(np.float64)
        for name, edge in (("points", 0.0), ("mesh+points", 0.10), ("no rule", np.inf)):
            got, _ = reproject_depth(depth, depth, KINECT_V2_DEPTH, transform, max_edge_m=edge)
            seen = silhouette & (got > 0)
            ghosts = (got > 0) & (truth > 0) & (got < truth - 0.10)
            key = f"{label} {name}"
            figures[f"{key} holes %"] = 100.0 * float((silhouette & (got == 0)).sum())
            figures[f"{key} holes %"] /= float(silhouette.sum())
            figures[f"{key} error mm"] = 1000.0 * float(np.median(np.abs(got - truth)[seen]))
            figures[f"{key} ghosts %"] = 100.0 * float(ghosts.sum()) / truth.size
    return figures


def in_sensor_view(truth: FloatArray, T_ref_from_sensor: FloatArray) -> npt.NDArray[np.bool_]:
    """Reference pixels whose true surface point lies inside the sensor's image (a sensor
    looking up does not see the legs: those are not holes of the re-projection)."""
    k = KINECT_V2_DEPTH
    points = apply(invert(T_ref_from_sensor), truth[..., None] * pixel_rays(k))
    z = np.where(points[..., 2] > 1e-6, points[..., 2], np.nan)
    with np.errstate(invalid="ignore"):
        u = k.cx - k.fx * points[..., 0] / z
        v = k.cy - k.fy * points[..., 1] / z
        inside = (u > -0.5) & (u < k.width - 0.5) & (v > -0.5) & (v < k.height - 0.5)
    return inside


def frame_times(compiled: bool, runs: int = 20) -> float:
    """Median ms of one 512×424 depth + IR re-projection (uint16 mm), 20° pitch + roll."""
    pose = head_pose(20.0, 20.0)
    depth = render_depth(default_room(), standing_pose()[None], pose, rng=np.random.default_rng(0))
    depth_mm = np.rint(depth * 1000.0).astype(np.uint16)
    ir = (depth_mm // 4).astype(np.uint16)
    transform = reference_from_sensor(pose)
    reproject_depth(depth_mm, ir, KINECT_V2_DEPTH, transform, compiled=compiled)  # compile/load
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        reproject_depth(depth_mm, ir, KINECT_V2_DEPTH, transform, compiled=compiled)
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)  # --help
    print(
        "| pitch, roll | input | own holes % | points holes % | mesh+points holes % | "
        "error mm | ghosts % (rule / none) |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for seed, (pitch, roll) in enumerate(CASES):
        f = case_figures(pitch, roll, seed)
        for label in ("ideal", "noisy", "hard edges"):
            print(
                f"| {pitch:+.0f}°, {roll:+.0f}° | {label} | {f['own holes %']:.1f} | "
                f"{f[f'{label} points holes %']:.1f} | {f[f'{label} mesh+points holes %']:.1f} | "
                f"{f[f'{label} mesh+points error mm']:.1f} | "
                f"{f[f'{label} mesh+points ghosts %']:.3f} / {f[f'{label} no rule ghosts %']:.3f} |"
            )
    print(f"\nload average before timing: {os.getloadavg()}")
    for compiled in (True, False):
        name = "numba loop" if compiled else "numpy"
        print(f"{name}: {frame_times(compiled):.1f} ms per 512x424 depth + IR frame (median of 20)")
    print(f"load average after timing: {os.getloadavg()}")
