"""Replay speed and BVH round trip, on a simulated recording.

A recording is generated offline in the skelfuse recording format: 4 simulated Kinect v2 (3 m
from the centre, 90° apart, unsynchronised phases, 2 ms network delay) watching the demo's
2-person routine for 5 minutes; each frame is encoded to wire bytes and stored with its
arrival time, exactly as the server's recorder stores it. Then:

- **replay speed**: ``recording.replay.replay`` fuses it (the server's fusion engine, recorded
  time);
  speed = recorded duration ÷ wall-clock time of the replay (× real time);
- **determinism**: every replay must give byte-identical fused JSON;
- **BVH round trip**: each fused person longer than 10 s is exported to BVH (30 fps), read back,
  forward kinematics run, and the positions compared with the fused joints (mean, p95, max).

Run: ``python -m bench replay`` (``--minutes 1`` for a quicker run, ``--runs N`` replays, the
median reported, ``--json FILE`` to save; the stages' warm-up is reported apart and not counted
in the replay times).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from skelfuse.agent.sim.kinect_model import SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.fusion.engine import FusedFrame
from skelfuse.protocol.feed import frame_json
from skelfuse.protocol.recording_file import Header, pack_record
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.recording.export_bvh import export_bvh, roundtrip_errors_m
from skelfuse.recording.replay import ReplayStats, replay
from skelfuse.recording.take import take_from_frames

FPS = 30.0
NETWORK_DELAY_S = 0.002
T0 = 1_800_000_000.0


def generate_recording(
    path: Path, sensors: int = 4, persons: int = 2, duration_s: float = 300.0, seed: int = 0
) -> int:
    """Write a simulated recording; returns its size in bytes."""
    rng = np.random.default_rng(seed)
    performer = ProceduralPerformer(persons)
    poses = []
    for k in range(sensors):
        angle = 2 * math.pi * k / sensors + math.radians(15.0)
        poses.append(look_at_pose((3 * math.sin(angle), 1.0, 3 * math.cos(angle)), (0, 0.9, 0)))
    names = [f"sim-{k + 1}" for k in range(sensors)]
    kinects = [SimulatedKinect(p, seed=seed * 100 + k) for k, p in enumerate(poses)]
    header = Header(T0, "bench", "bench replay", {}, {n: {"type": "sim"} for n in names})
    with path.open("wb") as out:
        out.write(header.to_msgpack())
        for k, name in enumerate(names):
            hello = Hello(name, "sim", "bench", FPS, 0, pose_hint=poses[k],
                          pose_hint_source="sim_truth")  # fmt: skip
            out.write(pack_record(round(T0 * 1e9), name, "hello", encode(hello)))
        events: list[tuple[float, int]] = []
        for k in range(sensors):
            phase = rng.uniform(0, 1 / FPS)
            events += [(T0 + phase + n / FPS, k) for n in range(int(duration_s * FPS))]
        events.sort()
        seqs = [0] * sensors
        for t_capture, k in events:
            truth = performer.joints_at(t_capture)
            observations = kinects[k].observe(truth, t_capture)
            seqs[k] += 1
            bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in observations)
            frame = Frame(seqs[k], int(t_capture * 1e9), bodies, kinects[k].floor_plane())
            t_arrival = round((t_capture + NETWORK_DELAY_S) * 1e9)
            out.write(pack_record(t_arrival, names[k], "frame", encode(frame)))
        out.write(pack_record(round((events[-1][0] + NETWORK_DELAY_S) * 1e9), "", "end", b""))
    return path.stat().st_size


def fused_digest(path: Path) -> tuple[str, list[FusedFrame], float, float]:
    """Replay ``path``: the fused frames' digest, the frames, the replay's seconds without the
    stages' warm-up, and the warm-up's seconds (compiling, or loading numba's cache)."""
    stats = ReplayStats()
    started = time.perf_counter()
    frames = list(replay(path, stats=stats))
    elapsed = time.perf_counter() - started - stats.warm_up_s
    digest = hashlib.sha256()
    for frame in frames:
        digest.update(
            json.dumps(frame_json(frame, include_raw=False), separators=(",", ":")).encode()
        )
    return digest.hexdigest(), frames, elapsed, stats.warm_up_s


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--sensors", type=int, default=4)
    parser.add_argument("--persons", type=int, default=2)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--runs", type=int, default=3, help="replays of the same recording")
    args = parser.parse_args(argv)
    duration = args.minutes * 60
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.sfrec"
        started = time.perf_counter()
        size = generate_recording(path, args.sensors, args.persons, duration)
        generated = time.perf_counter() - started
        runs = [fused_digest(path) for _ in range(args.runs)]
    frames = runs[0][1]
    warm_up_s = max(run[3] for run in runs)
    times = sorted(run[2] for run in runs)
    take = take_from_frames(frames)
    rows = []
    for person in take.persons.values():
        if person.times_s[-1] - person.times_s[0] < 10.0:
            continue
        for stretch in (False, True):
            export = export_bvh(person, fps=30.0, stretch=stretch)
            errors = roundtrip_errors_m(export.joints_m, export.text) * 1000
            rows.append({"person": person.person_id, "frames": export.frames,
                         "mode": "stretch" if stretch else "rigid",
                         "mean_mm": float(errors.mean()),
                         "p95_mm": float(np.percentile(errors, 95)),
                         "max_mm": float(errors.max())})  # fmt: skip
    median = statistics.median(times)
    identical = len({run[0] for run in runs}) == 1
    result = {
        "sensors": args.sensors, "persons": args.persons, "duration_s": duration,
        "file_mb": size / 1e6, "generate_s": generated, "replay_s": times,
        "speed_x_realtime": duration / median, "warm_up_s": warm_up_s, "fused_frames": len(frames),
        "deterministic": identical, "bvh": rows,
    }  # fmt: skip
    print(f"\nReplay: {args.sensors} sensors, {args.persons} persons, {duration:.0f} s recorded, "
          f"{size / 1e6:.1f} MB\n")  # fmt: skip
    print("| measure | value |")
    print("|---|---:|")
    print(f"| replay wall time (median of {len(runs)}) | {median:.2f} s |")
    print(f"| replay speed | {duration / median:.1f}× real time |")
    print(f"| warm-up (not in the replay times) | {warm_up_s:.2f} s |")
    print(f"| fused frames | {len(frames)} |")
    print(f"| replays byte-identical | {'yes' if identical else 'NO'} |")
    print("\n| person | BVH bones | frames | round trip mean mm | p95 mm | max mm |")
    print("|---:|---|---:|---:|---:|---:|")
    for row in rows:
        print(f"| {row['person']} | {row['mode']} | {row['frames']} | {row['mean_mm']:.2f} "
              f"| {row['p95_mm']:.2f} | {row['max_mm']:.3f} |")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0
