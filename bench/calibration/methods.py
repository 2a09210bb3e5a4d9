"""Calibration benchmark: how well each method finds where the sensors stand.

Random layouts of 2–5 simulated Kinect v2 sensors around the capture area (30°–180° from the
reference sensor, 1–4 m from the centre, 0.5–2.0 m high, each aimed at a point near the centre
at torso height, so high sensors are pitched down and low ones up), in the simulated room of
:mod:`agent.sim.room` (8 m × 8 m, six furniture boxes near the walls). The truth is known.

Per layout, one person (the demo's built-in routine: a walked circle of 0.9 m radius, a turn on
the spot, arm raises) is observed for ``--seconds`` (default 20 s) at 30 fps by every sensor
with the default :class:`KinectV2Params` (facing bias 0.5, mirrored back views, drift,
glitches, dropouts: nothing is weakened for the benchmark). The sensors are sampled at the same
instants, as the server's interpolation provides them (docs/fusion.md §3). Each sensor also
captures one depth point cloud (:func:`agent.sim.room.capture_point_cloud`, person included)
at t = 3 s.

Methods, each giving every non-reference sensor's pose relative to the reference:

- points: 4 positions of a marker (e.g. a ball on a stand) in the shared view, picked by hand in
  both sensors' views with σ = 1.5 cm per axis of picking noise → :func:`fit_rigid`;
- skeleton: :func:`solve_from_skeletons` on the two sensors' skeletons;
- skeleton→ICP and points→ICP: :func:`refine_all` from those initial guesses;
- floor: :func:`fit_floor` on each sensor's cloud (tilt and height error of the floor in that
  sensor's frame), and the Kinect's own floor plane (``SimulatedKinect.floor_plane``, which the
  simulator derives from the true pose: a sanity row, not a measurement of the real SDK).

Errors: rotation (degrees) and translation (mm) of ``T_ref_from_sensor``, median and 95th
percentile over all non-reference sensors of all layouts; run time per layout.

Run: ``python -m bench calibration`` (``--layouts N``, ``--seed S``, ``--json FILE``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.kinect_model import KinectV2Params, SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.room import Room, capture_point_cloud, default_room
from skelfuse.calibration.errors import CalibrationError
from skelfuse.calibration.floor import fit_floor, floor_error, floor_from_kinect_plane
from skelfuse.calibration.icp import IcpResult, refine_all
from skelfuse.calibration.rigid import fit_rigid, pose_error
from skelfuse.calibration.skeleton_pose import SKELETON_ERROR_BOUND, solve_from_skeletons
from skelfuse.protocol.transform import Matrix4, apply, invert, look_at_pose

F64 = npt.NDArray[np.float64]
FPS = 30.0
PICK_NOISE_M = 0.015
CAPTURE_T_S = 3.0


@dataclass
class Layout:
    poses: list[Matrix4]  # true T_world_from_sensor; index 0 is the reference


def make_layout(rng: np.random.Generator, room: Room) -> Layout:
    count = int(rng.integers(2, 6))
    ref_azimuth = rng.uniform(0, 2 * math.pi)
    poses: list[Matrix4] = []
    while len(poses) < count:
        if poses:
            offset = math.radians(rng.uniform(30, 180)) * (1 if rng.random() < 0.5 else -1)
        else:
            offset = 0.0
        azimuth = ref_azimuth + offset
        distance = rng.uniform(1.0, 4.0)
        x, z = distance * math.sin(azimuth), distance * math.cos(azimuth)
        height = rng.uniform(0.5, 2.0)
        if max(abs(x), abs(z)) > room.wall_half_m - 0.1 or _inside_box(room, (x, height, z)):
            continue
        target = (rng.uniform(-0.3, 0.3), 0.9, rng.uniform(-0.3, 0.3))
        poses.append(look_at_pose((x, height, z), target))
    return Layout(poses)


def _inside_box(room: Room, point: tuple[float, float, float]) -> bool:
    p = np.asarray(point)
    return any(
        bool(np.all(p >= np.asarray(b.min_m) - 0.2) and np.all(p <= np.asarray(b.max_m) + 0.2))
        for b in room.boxes
    )


def observe_all(
    layout: Layout, seconds: float, seed: int
) -> list[tuple[F64, npt.NDArray[np.uint8]]]:
    performer = ProceduralPerformer(1)
    kinects = [
        SimulatedKinect(p, KinectV2Params(), seed=seed + i) for i, p in enumerate(layout.poses)
    ]
    times = np.arange(0.0, seconds, 1 / FPS)
    out = []
    for _ in kinects:
        out.append((np.full((len(times), 25, 3), np.nan), np.zeros((len(times), 25), np.uint8)))
    for i, t in enumerate(times):
        joints = performer.joints_at(float(t))
        for k, kinect in enumerate(kinects):
            seen = kinect.observe(joints, float(t))
            if seen:
                out[k][0][i] = seen[0].joints_m
                out[k][1][i] = seen[0].states
    return out


def _visible(pose: Matrix4, point: F64, params: KinectV2Params) -> bool:
    p = apply(invert(pose), point)
    if p[2] <= 0:
        return False
    tan_h = math.tan(math.radians(params.fov_horizontal_deg / 2))
    tan_v = math.tan(math.radians(params.fov_vertical_deg / 2))
    distance = float(np.linalg.norm(p))
    return bool(
        abs(p[0]) <= 0.9 * p[2] * tan_h
        and abs(p[1]) <= 0.9 * p[2] * tan_v
        and params.min_range_m + 0.2 <= distance <= params.max_range_m - 0.2
    )


def points_method(pose_ref: Matrix4, pose_other: Matrix4, rng: np.random.Generator) -> Matrix4:
    """4 marker positions both sensors see, picked with noise, then Kabsch."""
    params = KinectV2Params()
    markers: list[F64] = []
    for _ in range(400):
        r, a = 1.5 * math.sqrt(rng.random()), rng.uniform(0, 2 * math.pi)
        candidate = np.array([r * math.sin(a), rng.uniform(0.2, 1.8), r * math.cos(a)])
        if (
            _visible(pose_ref, candidate, params)
            and _visible(pose_other, candidate, params)
            and all(np.linalg.norm(candidate - m) > 0.5 for m in markers)
        ):
            markers.append(candidate)
        if len(markers) == 4:
            break
    world = np.array(markers).reshape(-1, 3)
    in_ref = apply(invert(pose_ref), world) + rng.normal(scale=PICK_NOISE_M, size=world.shape)
    in_other = apply(invert(pose_other), world) + rng.normal(scale=PICK_NOISE_M, size=world.shape)
    return fit_rigid(in_other, in_ref).T_dst_from_src


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


Stats = dict[str, dict[str, list[float]]]
"""Method → measure (``rot_deg``, ``trans_mm``, ``time_s``, ``failures`` ...) → values."""


def run(layouts: int, seed: int, seconds: float) -> Stats:
    rng = np.random.default_rng(seed)
    room = default_room()
    stats: Stats = defaultdict(lambda: defaultdict(list))
    for index in range(layouts):
        layout = make_layout(rng, room)
        truth_ref = layout.poses[0]
        relative_truth = [invert(truth_ref) @ p for p in layout.poses]
        skeletons = observe_all(layout, seconds, seed * 1000 + index * 10)
        performer = ProceduralPerformer(1)
        started = time.perf_counter()
        clouds = {
            f"s{k}": capture_point_cloud(room, performer.joints_at(CAPTURE_T_S), pose, rng)
            for k, pose in enumerate(layout.poses)
        }
        stats["depth capture (all sensors)"]["time_s"].append(time.perf_counter() - started)
        for method in ("points", "skeleton"):
            started = time.perf_counter()
            inits = _initial_poses(method, layout, skeletons, relative_truth, rng, stats, index)
            stats[method]["time_s"].append(time.perf_counter() - started)
            started = time.perf_counter()
            _refine(method, clouds, inits, relative_truth, stats, index)
            stats[f"{method}→ICP"]["time_s"].append(time.perf_counter() - started)
        _floors(layout, clouds, stats, index)
        print(f"layout {index + 1}/{layouts}: {len(layout.poses)} sensors", file=sys.stderr)
    return stats


def _initial_poses(
    method: str,
    layout: Layout,
    skeletons: list[tuple[F64, npt.NDArray[np.uint8]]],
    relative_truth: list[Matrix4],
    rng: np.random.Generator,
    stats: Stats,
    index: int,
) -> dict[str, Matrix4]:
    """Each sensor's pose in the reference's frame by ``method`` (``points`` or ``skeleton``),
    its error against ``relative_truth`` added to ``stats``; the sensors it failed for left out."""
    truth_ref = layout.poses[0]
    inits: dict[str, Matrix4] = {"s0": np.eye(4)}
    for k in range(1, len(layout.poses)):
        try:
            if method == "points":
                estimate = points_method(truth_ref, layout.poses[k], rng)
            else:
                fit = solve_from_skeletons(*skeletons[0], *skeletons[k])
                estimate = fit.T_ref_from_other
                stats[method]["trust_" + fit.trust].append(1.0)
        except CalibrationError as exc:
            stats[method]["failures"].append(1.0)
            print(f"layout {index} sensor {k} {method}: {exc}", file=sys.stderr)
            continue
        inits[f"s{k}"] = estimate
        rot, trans = pose_error(estimate, relative_truth[k])
        stats[method]["rot_deg"].append(rot)
        stats[method]["trans_mm"].append(trans)
    return inits


def _refine(
    method: str,
    clouds: dict[str, npt.NDArray[np.float32]],
    inits: dict[str, Matrix4],
    relative_truth: list[Matrix4],
    stats: Stats,
    index: int,
) -> None:
    """ICP from ``method``'s poses; the refined poses' errors added to ``stats``."""
    usable = {k: v for k, v in clouds.items() if k in inits}
    try:
        cap = SKELETON_ERROR_BOUND if method == "skeleton" else None
        results: dict[str, IcpResult] = refine_all(usable, inits, "s0", max_correction=cap)
    except CalibrationError as exc:
        print(f"layout {index} {method}→ICP: {exc}", file=sys.stderr)
        results = {}
    name = f"{method}→ICP"
    for sensor, init in inits.items():
        if sensor == "s0":
            continue
        result = results.get(sensor)
        final = result.T_target_from_source if result is not None else init
        rot, trans = pose_error(final, relative_truth[int(sensor[1:])])
        stats[name]["rot_deg"].append(rot)
        stats[name]["trans_mm"].append(trans)
        if result is not None:
            stats[name]["applied"].append(float(result.applied))
            stats[name]["dofs6"].append(float(result.constrained_dofs == 6))


def _floors(
    layout: Layout, clouds: dict[str, npt.NDArray[np.float32]], stats: Stats, index: int
) -> None:
    """The floor fitted in each sensor's cloud and the Kinect's own plane, their errors added
    to ``stats``."""
    started = time.perf_counter()
    for k, pose in enumerate(layout.poses):
        try:
            floor = fit_floor(clouds[f"s{k}"])
        except CalibrationError as exc:
            stats["floor (depth fit)"]["failures"].append(1.0)
            print(f"layout {index} sensor {k} floor: {exc}", file=sys.stderr)
            continue
        tilt, height = floor_error(floor, pose)
        stats["floor (depth fit)"]["tilt_deg"].append(tilt)
        stats["floor (depth fit)"]["height_mm"].append(abs(height))
    stats["floor (depth fit)"]["time_s"].append(time.perf_counter() - started)
    for pose in layout.poses:
        kinect_floor = floor_from_kinect_plane(*SimulatedKinect(pose).floor_plane())
        tilt, height = floor_error(kinect_floor, pose)
        stats["floor (Kinect plane)"]["tilt_deg"].append(tilt)
        stats["floor (Kinect plane)"]["height_mm"].append(abs(height))


def table(stats: dict[str, dict[str, list[float]]], layouts: int) -> str:
    lines = [
        "| method | sensors | rotation median ° | rotation p95 ° | translation median mm "
        "| translation p95 mm | failures | time per layout s | notes |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for name in ("points", "skeleton", "points→ICP", "skeleton→ICP"):
        s = stats[name]
        notes = ""
        if "applied" in s:
            notes = (
                f"applied {np.mean(s['applied']):.0%}, all 6 DOF constrained "
                f"{np.mean(s['dofs6']):.0%}"
            )
        if name == "skeleton":
            notes = ", ".join(
                f"trust {level}: {len(s.get('trust_' + level, []))}"
                for level in ("high", "medium", "low")
            )
        lines.append(
            f"| {name} | {len(s['rot_deg'])} | {np.median(s['rot_deg']):.2f} | "
            f"{percentile(s['rot_deg'], 95):.2f} | {np.median(s['trans_mm']):.1f} | "
            f"{percentile(s['trans_mm'], 95):.1f} | {len(s.get('failures', []))} | "
            f"{np.mean(s['time_s']):.2f} | {notes} |"
        )
    lines += [
        "",
        "| floor | sensors | tilt median ° | tilt p95 ° | height error median mm "
        "| height error p95 mm | failures | time per layout s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name in ("floor (depth fit)", "floor (Kinect plane)"):
        s = stats[name]
        time_text = f"{np.mean(s['time_s']):.2f}" if s.get("time_s") else "–"
        lines.append(
            f"| {name} | {len(s['tilt_deg'])} | {np.median(s['tilt_deg']):.3f} | "
            f"{percentile(s['tilt_deg'], 95):.3f} | {np.median(s['height_mm']):.1f} | "
            f"{percentile(s['height_mm'], 95):.1f} | {len(s.get('failures', []))} | "
            f"{time_text} |"
        )
    capture = stats["depth capture (all sensors)"]["time_s"]
    lines.append("")
    lines.append(
        f"{layouts} layouts; depth capture (render + back-project + voxel grid, all sensors of "
        f"a layout): {np.mean(capture):.2f} s per layout."
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--layouts", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    stats = run(args.layouts, args.seed, args.seconds)
    sys.stdout.write(table(stats, args.layouts) + "\n")
    sys.stdout.write(f"\nTotal run time: {time.perf_counter() - started:.0f} s\n")
    if args.json is not None:
        args.json.write_text(
            json.dumps({k: dict(v) for k, v in stats.items()}, indent=1), encoding="utf-8"
        )
