"""The real four-camera clip fused in simulated time, for the lead / lag against the views.

Each camera is an ``rgb`` sensor whose frames are the ``mono`` source's bodies of the landmark
fixture (:func:`bench.mono.live.camera_bodies`: PnP placement of MediaPipe's landmarks, the
25-joint model in the sensor frame), registered at its calibrated pose and fed as wire bytes
to a production ``FusionHub`` in simulated time (as ``bench/accuracy/runner.py`` feeds the
simulator's frames), each frame arriving :data:`NETWORK_DELAY_S` after its capture. Camera
frame i is stamped at (i − lag) / 60 s, the lag from the product's motion sync, so the
stamps are the cameras' real capture times (the clip's cameras are synchronised but for
cam03's lag). Every camera holds the clip's first frame for ``hold_s`` first, so that the
person is born and the alignment has chosen its grid before the motion starts.

Two timings of the same motion: ``synchronised`` (every camera at 60 fps, as recorded) and
``staggered`` (every camera at 30 fps, cam01 and cam03 from the even frames, cam02 and cam04
from the odd ones: half the sensors captured a half period after the others, late at every
instant under the ``deadline`` policy, on real motion).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.accuracy.view_shift import Take
from bench.mono.geometry import load_cameras
from bench.mono.live import camera_bodies
from bench.mono.single import CALIBRATION, CAMERAS, FPS, load_clip, motion_sync_lags
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import FusionSettings, Settings

T0 = 1_800_000_000.0
NETWORK_DELAY_S = 0.002
TIMINGS = ("synchronised", "staggered")


@dataclass(frozen=True)
class ClipFrames:
    """Every camera's bodies (frame i: (25, 3) sensor-frame metres, (25,) states), its pose
    (``T_world_from_sensor``) and its lag behind cam01 (frames)."""

    bodies: dict[str, list[tuple[np.ndarray, np.ndarray]]]
    poses: dict[str, np.ndarray]
    lags: dict[str, float]


def load_frames() -> ClipFrames:
    """The fixture's bodies as the ``mono`` source sends them, per camera."""
    clip, cameras = load_clip(), load_cameras(CALIBRATION)
    lags = motion_sync_lags(clip, cameras)
    bodies = {name: camera_bodies(clip, cameras[name], name) for name in CAMERAS}
    poses = {name: cameras[name].T_world_from_sensor for name in CAMERAS}
    return ClipFrames(bodies, poses, lags)


def events(frames: ClipFrames, timing: str, hold_s: float) -> list[tuple[float, str, int, int]]:
    """(capture time since T0 in s, camera, sequence number, clip frame) of every frame sent,
    in capture order; clip frame −1 is the held first frame."""
    out: list[tuple[float, str, int, int]] = []
    for k, name in enumerate(CAMERAS):
        step, first = (2, k % 2) if timing == "staggered" else (1, 0)
        held = round(hold_s * FPS) // step
        start = (first - frames.lags.get(name, 0.0)) / FPS  # clip frame ``first``'s capture
        shown = [-1] * held + list(range(first, len(frames.bodies[name]), step))
        for seq, clip_frame in enumerate(shown):
            out.append((start + (seq - held) * step / FPS, name, seq + 1, clip_frame))
    return sorted(out)


def clip_take(fusion: FusionSettings, timing: str, hold_s: float = 1.0) -> Take:
    """The clip fused by a fresh hub with ``fusion`` settings; the views and fused frames."""
    frames = load_frames()
    hub = FusionHub(Settings(fusion=fusion))
    rate = FPS / (2 if timing == "staggered" else 1)
    for name in CAMERAS:
        hello = Hello(name, "rgb", "bench", rate, 0, pose_hint=frames.poses[name],
                      pose_hint_source="manual")  # fmt: skip
        hub.handle_message(name.encode(), [encode(hello)], T0, 0.0)
    take = Take()
    for at, name, seq, clip_frame in events(frames, timing, hold_s):
        first = 1 if timing == "staggered" and CAMERAS.index(name) % 2 else 0
        joints, states = frames.bodies[name][clip_frame if clip_frame >= 0 else first]
        seen = np.isfinite(joints[states > 0]).all()
        bodies = (Body(1, joints.astype(np.float32), states),) if seen else ()
        t_capture = T0 + hold_s + at
        message = encode(Frame(seq, int(t_capture * 1e9), bodies))
        received = t_capture + NETWORK_DELAY_S
        hub.handle_message(name.encode(), [message], received, received - T0)
        sensor = hub.sensors[name]
        if sensor.frames and sensor.frames[-1].frame.seq == seq:
            newest = sensor.frames[-1]
            take.add_view(name, newest.t_server_s, newest.frame, frames.poses[name], "rgb")
        fused = hub.fuse_step(received)
        if fused is not None:
            take.add_fused(fused)
    return take
