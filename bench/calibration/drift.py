"""Drift benchmark: is a bumped sensor flagged in time, and is nothing flagged otherwise?

Simulated Kinect v2 sensors (3 on a 3 m circle, ``bench.accuracy.runner.sensor_poses``) watch
the built-in routine (walk a circle, turn, arm raises, squats, looped). One production
:class:`server.hub.FusionHub` with ``drift.enabled`` on receives every frame as wire bytes in
simulated time (as ``bench/accuracy/runner.py`` drives it), calibrated with the true poses.

- **bump**: ``--bump-at`` seconds into the take, or whole routine loops later (the same point
  of the routine, so times compare with runs before the baseline) once the sensor has a
  baseline (a bump before it would be part of it: ``fusion/drift.py``), one sensor's true
  pose changes (a rotation about
  its own vertical axis, a shift along its own x, or both) while the hub keeps the committed pose;
  reported: when the bump happened (the baseline's wait), the time from the bump to the flag
  (fusion instants), and any sensor flagged that was not bumped, or before the bump;
- **normal**: a take of ``--minutes`` of the routine with nothing bumped; reported: the
  flags (false alarms), the largest correction per sensor relative to its baseline as it
  counts against the sensor (the rotation only from ``ROTATION_MIN_SPREAD_M`` on), the largest
  correction under the committed calibration (what flagged before the baseline), and the wall
  time; once calibrated with the true poses, once with one sensor's committed pose off by
  ``MISCALIBRATION`` (a constant calibration error, as a self-calibrated rig has).

Run: ``python -m bench drift`` (``--seeds N`` bump takes per bump, ``--normal-seeds N`` normal
takes of ``--minutes M``, ``--json FILE``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench.accuracy.runner import FPS, NETWORK_DELAY_S, T0, sensor_poses
from skelfuse.agent.sim.kinect_model import KinectV2Params, SimulatedKinect
from skelfuse.agent.sim.performer import Choreography, ProceduralPerformer
from skelfuse.fusion.drift import ROTATION_MIN_SPREAD_M
from skelfuse.fusion.settings import DriftSettings
from skelfuse.protocol.transform import axis_rotation, invert
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import FusionSettings, Settings

SETTINGS = FusionSettings(drift=DriftSettings(enabled=True))
LOOP_S = Choreography(radius_m=0.9).loop_s
"""The routine's loop (its first person's: ``ProceduralPerformer``), seconds."""


@dataclass(frozen=True, slots=True)
class Bump:
    """Sensor ``sensor`` (index) turns ``yaw_deg`` about its own +Y and shifts ``shift_mm``
    along its own +X, ``at_s`` seconds into the take."""

    sensor: int
    yaw_deg: float
    shift_mm: float
    at_s: float


def bumped_pose(pose: np.ndarray, bump: Bump) -> np.ndarray:
    """(4, 4) ``T_world_from_sensor`` after ``bump`` (applied in the sensor's own frame)."""
    yaw = math.radians(bump.yaw_deg)
    delta = np.eye(4)
    delta[:3, :3] = axis_rotation("y", yaw)
    delta[0, 3] = bump.shift_mm / 1000.0
    result: np.ndarray = pose @ delta
    return result


def run_take(
    seed: int,
    duration_s: float,
    bump: Bump | None,
    settings: FusionSettings = SETTINGS,
    miscalibration: Bump | None = None,
) -> dict[str, object]:
    """One simulated take; the flags seen (sensor → first flag time after the start, s).
    ``miscalibration``: the committed pose of that sensor is its true pose moved so (from the
    start, ``at_s`` unused)."""
    rng = np.random.default_rng(seed)
    poses = sensor_poses(3)
    names = [f"sim-{k + 1}" for k in range(3)]
    kinects = [
        SimulatedKinect(p, KinectV2Params(), seed=seed * 100 + k) for k, p in enumerate(poses)
    ]
    hub = FusionHub(Settings(fusion=settings))
    committed = list(poses)
    if miscalibration is not None:
        committed[miscalibration.sensor] = bumped_pose(poses[miscalibration.sensor], miscalibration)
    for name, pose in zip(names, committed, strict=True):
        hello = Hello(name, "sim", "bench", FPS, 0, pose_hint=pose, pose_hint_source="sim_truth")
        hub.handle_message(name.encode(), [encode(hello)], T0, 0.0)
    assert hub.drift is not None
    performer = ProceduralPerformer(1)
    offset = rng.uniform(0, 30.0)  # where in the routine the take starts
    events: list[tuple[float, int]] = []
    for k in range(3):
        phase = rng.uniform(0, 1 / FPS)
        events += [(T0 + phase + n / FPS, k) for n in range(int(duration_s * FPS))]
    events.sort()
    seqs = [0] * 3
    bumped = False
    bumped_at: float | None = None
    next_bump_s = math.inf if bump is None else bump.at_s
    flags: dict[str, float] = {}
    largest: dict[str, tuple[float, float]] = {}
    largest_raw: dict[str, tuple[float, float]] = {}
    started = time.perf_counter()
    for t_capture, k in events:
        if bump is not None and not bumped and t_capture - T0 >= next_bump_s:
            target_state = hub.drift.sensors.get(names[bump.sensor])
            if target_state is None or target_state.baseline is None:
                next_bump_s += LOOP_S  # no baseline yet: a loop later, same point of the routine
        if bump is not None and not bumped and t_capture - T0 >= next_bump_s:
            moved = bumped_pose(poses[bump.sensor], bump)
            target = kinects[bump.sensor]
            target.T_world_from_sensor = moved
            target._T_sensor_from_world = invert(moved)  # the simulator has no setter
            bumped, bumped_at = True, t_capture - T0
        truth = performer.joints_at(t_capture - T0 + offset)
        observations = kinects[k].observe(truth, t_capture)
        seqs[k] += 1
        bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in observations)
        message = encode(Frame(seqs[k], int(t_capture * 1e9), bodies))
        received = t_capture + NETWORK_DELAY_S
        hub.handle_message(names[k].encode(), [message], received, received - T0)
        fused = hub.fuse_step(received)
        if fused is None:
            continue
        for name, state in hub.drift.sensors.items():
            if state.moved and name not in flags:
                flags[name] = fused.t_s - T0
            for c, table in ((state.relative, largest), (state.correction, largest_raw)):
                if c is not None:  # the rotation as it counts (drift.Correction.severity)
                    old = table.get(name, (0.0, 0.0))
                    rotation = c.rotation_deg if c.spread_m >= ROTATION_MIN_SPREAD_M else 0.0
                    table[name] = (max(old[0], rotation), max(old[1], c.shift_mm))
    return {
        "flags": flags,
        "largest": {k: (round(v[0], 2), round(v[1], 1)) for k, v in sorted(largest.items())},
        "largest_raw": {
            k: (round(v[0], 2), round(v[1], 1)) for k, v in sorted(largest_raw.items())
        },
        "wall_s": time.perf_counter() - started,
        "target": None if bump is None else names[bump.sensor],
        "bumped_at": bumped_at,
    }


MISCALIBRATION = Bump(1, 3.0, 60.0, 0.0)
"""The committed pose of sim-2 off by 3° and 60 mm in the miscalibrated normal take."""

BUMPS = {
    "2° yaw": Bump(1, 2.0, 0.0, 20.0),
    "30 mm shift": Bump(1, 0.0, 30.0, 20.0),
    "2° + 30 mm": Bump(1, 2.0, 30.0, 20.0),
    "5° + 50 mm": Bump(1, 5.0, 50.0, 20.0),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--minutes", type=float, default=10.0, help="normal take length")
    parser.add_argument("--normal-seeds", type=int, default=1, help="normal takes")
    parser.add_argument("--bump-at", type=float, default=20.0, help="seconds into a bump take")
    parser.add_argument("--after", type=float, default=20.0, help="seconds a bump take goes on")
    parser.add_argument(
        "--wait", type=float, default=2 * LOOP_S, help="longest wait for a baseline after --bump-at"
    )
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    out: dict[str, object] = {}
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(
        "| bump | detected (seeds) | bumped at, median (latest) | time to flag, median (worst) "
        "| wrongly flagged |"
    )
    print("|---|---|---|---|---|")
    for label, bump in BUMPS.items():
        bump = replace(bump, at_s=args.bump_at)
        times: list[float] = []
        starts: list[float] = []
        wrong = 0
        for seed in range(args.seeds):
            take = run_take(seed, args.bump_at + args.wait + args.after, bump)
            flags, at = take["flags"], take["bumped_at"]
            assert isinstance(flags, dict)
            target = take["target"]
            wrong += sum(1 for n, t in flags.items() if n != target or at is None or t < at)
            if isinstance(at, float):
                starts.append(at)
                if target in flags and flags[target] >= at:
                    times.append(flags[target] - at)
            out[f"{label} seed {seed}"] = take
        detected = f"{len(times)}/{args.seeds}"
        when = f"{statistics.median(times):.1f} s ({max(times):.1f} s)" if times else "-"
        bumped = f"{statistics.median(starts):.0f} s ({max(starts):.0f} s)" if starts else "never"
        print(f"| {label} | {detected} | {bumped} | {when} | {wrong} |")
    print()
    print(
        "| normal take | minutes | false alarms | largest change since the baseline (°, mm) "
        "| largest correction under the calibration (°, mm) | wall |"
    )
    print("|---|---|---|---|---|---|")
    for seed in range(args.normal_seeds):
        for label, error in (("calibrated", None), ("sim-2 off 3° + 60 mm", MISCALIBRATION)):
            take = run_take(1000 + seed, args.minutes * 60.0, None, miscalibration=error)
            flags = take["flags"]
            assert isinstance(flags, dict)
            print(
                f"| seed {seed}, {label} | {args.minutes:g} | {len(flags)} | {take['largest']} "
                f"| {take['largest_raw']} | {take['wall_s']:.0f} s |"
            )
            out[f"normal seed {seed} {label}"] = take
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=str))
    return 0
