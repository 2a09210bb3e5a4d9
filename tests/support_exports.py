"""A realistic take for the export tests, and the fused motion they are compared with.

The take is fused from a short simulated recording, the way a user's take is: 3 simulated
Kinect v2 watching the demo's 2-person routine, frames stamped with Unix-epoch capture times
(each sensor with its own phase, a clock running 100-200 ppm off and 2 ms of capture jitter),
arriving 2-5 ms later; every sensor goes silent for 0.6 s (longer than the 0.25 s that
resampling bridges) and for 0.15 s (shorter), so the fused tracks have one gap of each kind.
Replayed by the production hub (``recording.replay``), as ``skelfuse export`` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.kinect_model import SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.protocol.recording_file import Header, pack_record
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.recording.replay import replay
from skelfuse.recording.take import PersonTrack, Take, take_from_frames

F64 = npt.NDArray[np.float64]

MAX_GAP_S = 0.25
"""The longest gap exports bridge, as docs/recording.md documents it (seconds)."""

T0 = 1_795_000_000.123456
"""Start of the simulated take, Unix seconds (2026-11-18)."""
FPS = 30.0
LONG_OUTAGE_S = (3.0, 3.6)
"""Every sensor silent over this span (seconds after T0): longer than the resampling limit."""
SHORT_OUTAGE_S = (1.5, 1.65)
"""And over this one: shorter than the limit, so resampling bridges it."""


def write_simulated_recording(
    path: Path, *, sensors: int = 3, persons: int = 2, duration_s: float = 6.0, seed: int = 7
) -> None:
    """A ``.sfrec`` recording of simulated sensors (see the module docstring)."""
    rng = np.random.default_rng(seed)
    performer = ProceduralPerformer(persons)
    poses = []
    for k in range(sensors):
        angle = 2 * math.pi * k / sensors + math.radians(15.0)
        poses.append(look_at_pose((3 * math.sin(angle), 1.0, 3 * math.cos(angle)), (0, 0.9, 0)))
    names = [f"sim-{k + 1}" for k in range(sensors)]
    kinects = [SimulatedKinect(p, seed=seed * 100 + k) for k, p in enumerate(poses)]
    header = Header(T0, "test", "exports", {}, {n: {"type": "sim"} for n in names})
    with path.open("wb") as out:
        out.write(header.to_msgpack())
        for k, name in enumerate(names):
            hello = Hello(name, "sim", "test", FPS, 0, pose_hint=poses[k],
                          pose_hint_source="sim_truth")  # fmt: skip
            out.write(pack_record(round(T0 * 1e9), name, "hello", encode(hello)))
        events: list[tuple[float, int]] = []
        for k in range(sensors):
            phase = rng.uniform(0, 1 / FPS)
            rate = 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(1e-4, 2e-4)
            n = np.arange(int(duration_s * FPS))
            t = T0 + phase + n / FPS * rate + rng.normal(0.0, 0.002, n.size)
            events += [(float(x), k) for x in t]
        events.sort()
        seqs = [0] * sensors
        for t_capture, k in events:
            observations = kinects[k].observe(performer.joints_at(t_capture - T0), t_capture)
            seqs[k] += 1
            since = t_capture - T0
            if any(a <= since < b for a, b in (LONG_OUTAGE_S, SHORT_OUTAGE_S)):
                continue
            bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in observations)
            frame = Frame(seqs[k], int(t_capture * 1e9), bodies, kinects[k].floor_plane())
            t_arrival = round((t_capture + rng.uniform(0.002, 0.005)) * 1e9)
            out.write(pack_record(t_arrival, names[k], "frame", encode(frame)))
        out.write(pack_record(round((events[-1][0] + 0.01) * 1e9), "", "end", b""))


def simulated_take(folder: Path) -> Take:
    """The fused take of :func:`write_simulated_recording` (written into ``folder``)."""
    path = folder / "take.sfrec"
    write_simulated_recording(path)
    return take_from_frames(replay(path))


@dataclass(frozen=True, slots=True)
class Reference:
    """The fused motion at an export's instants.

    joints: (N, 25, 3) metres, world (+Y up); NaN where the export must be empty (a joint with
        no fused sample within :data:`MAX_GAP_S` around the instant).
    on_sample: (N,) True where the instant is a fused instant (to a microsecond), so the
        reference there is the fused frame itself, no interpolation.
    """

    joints: F64
    on_sample: npt.NDArray[np.bool_]


def fused_motion_at(track: PersonTrack, start_s: float, fps: float, count: int) -> Reference:
    """What an export at ``fps`` from ``start_s`` should hold, computed independently of
    ``recording.take``: ``np.interp`` per joint and axis on times relative to ``start_s``."""
    grid = np.arange(count) / fps
    times = track.times_s - start_s
    out = np.full((count, 25, 3), np.nan)
    for j in range(25):
        known = np.isfinite(track.joints[:, j]).all(axis=1)
        t = times[known]
        if t.size == 0:
            continue
        for axis in range(3):
            out[:, j, axis] = np.interp(grid, t, track.joints[known, j, axis], np.nan, np.nan)
        nearest = np.abs(t[None, :] - grid[:, None]).min(axis=1)
        later = np.searchsorted(t, grid)
        gap = np.where(
            (later > 0) & (later < t.size),
            t[np.minimum(later, t.size - 1)] - t[np.maximum(later - 1, 0)],
            np.inf,
        )
        out[(nearest > 1e-6) & (gap > MAX_GAP_S), j] = np.nan
    on_sample = np.abs(times[None, :] - grid[:, None]).min(axis=1) <= 1e-6
    return Reference(out, on_sample)


def bvhio_positions_m(path: Path, names: list[str]) -> F64:
    """World positions (frames, names, 3) in metres as bvhio computes them (our BVH is in cm).

    Raises:
        ImportError: bvhio is not installed (it is in the dev extra).
    """
    import bvhio  # an independent reader: imported only where used

    root = bvhio.readAsHierarchy(str(path))
    joints = {joint.Name: joint for joint, _, _ in root.layout()}
    first, last = root.getKeyframeRange()
    out = np.zeros((last - first + 1, len(names), 3))
    for frame in range(first, last + 1):
        root.loadPose(frame, recursive=True)
        for k, name in enumerate(names):
            p = joints[name].PositionWorld
            out[frame - first, k] = (p.x, p.y, p.z)
    return out / 100.0


def ezc3d_world_m(path: Path, labels: list[str]) -> F64:
    """Markers ``labels`` (frames, markers, 3) as ezc3d reads them, back in our world frame
    (metres, +Y up); NaN where the residual is negative.

    Raises:
        ImportError: ezc3d is not installed (it is in the dev extra).
    """
    import ezc3d

    c3d = ezc3d.c3d(str(path))
    names = c3d["parameters"]["POINT"]["LABELS"]["value"]
    z_up = c3d["data"]["points"][:3, [names.index(n) for n in labels], :].transpose(2, 1, 0)
    world: F64 = np.stack([z_up[..., 0], z_up[..., 2], -z_up[..., 1]], axis=-1) / 1000.0
    return world


def _figures(fps: float) -> None:
    """Print each export's error against the fused motion, per reader (docs/benchmarks.md)."""
    import tempfile

    from skelfuse.protocol.bvh import forward_kinematics, read_bvh
    from skelfuse.protocol.skeleton import JOINT_NAMES
    from skelfuse.recording.export_bvh import export_bvh
    from skelfuse.recording.export_c3d import export_c3d
    from tests.support_blender import blender_bvh_positions, blender_executable

    def row(what: str, positions: F64, reference: Reference) -> None:
        errors = np.linalg.norm(positions - reference.joints, axis=-1) * 1000.0
        e = errors[np.isfinite(reference.joints[..., 0])]
        print(f"| {what} | {np.median(e):.2f} | {e.mean():.2f} | {np.percentile(e, 95):.2f} "
              f"| {e.max():.2f} | {e.size} |")  # fmt: skip

    names = list(JOINT_NAMES)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        take = simulated_take(folder)
        person = take.main_person()
        print(f"\nExports at {fps:g} fps of a simulated take: error vs the fused motion, mm\n")
        print("| export, reader | median | mean | p95 | max | joints x frames |")
        print("|---|---:|---:|---:|---:|---:|")
        files = []
        for mode in ("rigid", "stretch"):
            path = folder / f"{mode}.bvh"
            export = export_bvh(person, path, fps=fps, stretch=mode == "stretch")
            reference = fused_motion_at(person, float(person.times_s[0]), fps, export.frames)
            bvh = read_bvh(path)
            ours = forward_kinematics(bvh)[:, [bvh.index(n) for n in names]] / 100.0
            row(f"BVH {mode}, protocol/bvh.py", ours, reference)
            row(f"BVH {mode}, bvhio", bvhio_positions_m(path, names), reference)
            files.append((mode, path, reference))
        blender = blender_executable()
        if blender is not None:
            results = blender_bvh_positions(blender, [f for _, f, _ in files], folder / "b.json")
            for (mode, _, reference), result in zip(files, results, strict=True):
                columns = [result["bones"].index(n) for n in names]
                row(f"BVH {mode}, Blender", result["positions"][:, columns], reference)
        frames = export_c3d(take, folder / "take.c3d", fps=fps)
        for pid, track in take.persons.items():
            labels = [f"P{pid}_{n}" for n in names]
            reference = fused_motion_at(track, take.start_s, fps, frames)
            row(f"C3D person {pid}, ezc3d", ezc3d_world_m(folder / "take.c3d", labels), reference)


if __name__ == "__main__":
    for rate in (30.0, 60.0):
        _figures(rate)
