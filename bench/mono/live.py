"""Cameras of the real clip streamed live to a real server, and the fused joints it publishes.

Each camera is one agent (the real :func:`skelfuse.agent.runner.run_agent`, ZeroMQ on loopback)
whose source replays the landmark fixture: per frame, the ``mono`` source's own steps
(:func:`skelfuse.protocol.mediapipe_pose.body_from_landmarks`: PnP placement, visibility →
states, the 25-joint model in the sensor frame) on the stored landmarks, sent at 60 fps in real
time. This replays precomputed landmarks: the ``mono`` source's model stage is measured
elsewhere; everything after it (wire, ingest, clock offsets, interpolation, association, mirror
labels, confidence, fusion, filter) is the product's.

The server is ``python -m skelfuse server`` (``bench/live/server.py``) with the clip's
calibration stored for the streamed cameras. Every agent holds the clip's first frame for
``hold_s`` before the clip plays, so fusion has its person when the motion starts. Every camera
stamps its frame i at i / 60 s on its own clock; a camera whose frames lag by L frames (the
motion sync's finding, ``calibration/motion_sync.py``) has ``lag_s`` = L / 60 in the stored
calibration, and the server subtracts it from its times (``fusion/sensors.py``), as it does
for an imported or synced calibration.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from bench.live.server import ROOT, free_port, http_json, wait_for
from bench.mono.geometry import FloatArray, pinhole, undistorted_px
from bench.mono.single import FPS, Clip
from skelfuse.agent.runner import run_agent
from skelfuse.agent.sources.base import Capture, wait_for_due
from skelfuse.calibration.camera import Camera
from skelfuse.calibration.store import CalibrationStore, SensorCalibration
from skelfuse.client.sync import SyncFeedClient
from skelfuse.geometry.pnp import Placement
from skelfuse.parent_watch import child_environment
from skelfuse.protocol.mediapipe_pose import body_from_landmarks
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import SENSOR_TYPES, Body

SENSOR_TYPE = "rgb" if "rgb" in SENSOR_TYPES else "replay"
"""The wire type the replayed cameras register with: ``rgb`` once the protocol has it."""


@dataclass
class LiveRun:
    """What the server published while the clip played.

    times: (F,) clip frame index (fractional, the reference cameras' timeline) of each fused
    frame; joints: (F, 25, 3) world metres of the person fused from most sources (NaN where
    none); persons: (F,) persons published; mirrored: sensors the mirror step swapped, counted.
    """

    times: FloatArray
    joints: FloatArray
    persons: FloatArray
    mirrored: dict[str, int] = field(default_factory=dict)
    sources: dict[str, int] = field(default_factory=dict)


class LandmarkSource:
    """One camera's precomputed bodies, played on a shared schedule (a ``SkeletonSource``).

    ``start``: set by the bench to the clip's start (Unix ns) once every agent is registered;
    until then no frame goes out.
    """

    sensor_type = SENSOR_TYPE
    fps = FPS
    waits_for_server = True

    def __init__(
        self,
        bodies: list[tuple[FloatArray, np.ndarray]],
        hold_frames: int,
        start: list[int],
    ) -> None:
        self._bodies = bodies
        self._hold = hold_frames
        self._start = start
        self._next = 0

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None

    def next_capture(self, timeout_s: float) -> Capture | None:
        """The next scheduled frame, once its instant has come (None before or after the clip)."""
        if not self._start or self._next >= self._hold + len(self._bodies):
            time.sleep(timeout_s)
            return None
        stamp = self._start[0] + int(self._next / FPS * 1e9)
        if not wait_for_due(stamp, time.time_ns(), timeout_s, time.sleep):
            return None
        joints, states = self._bodies[max(0, self._next - self._hold)]
        self._next += 1
        if not np.isfinite(joints[states > 0]).all():
            return Capture(stamp, ())
        return Capture(stamp, (Body(1, joints.astype(np.float32), states),))

    def close(self) -> None:
        pass


def camera_bodies(clip: Clip, cam: Camera, name: str) -> list[tuple[FloatArray, np.ndarray]]:
    """Per frame, the camera's body as the ``mono`` source sends it: ((25, 3) m in the sensor
    frame, (25,) states); NaN joints where MediaPipe found nobody."""
    intrinsics = pinhole(cam)
    size = (cam.intrinsics.width, cam.intrinsics.height)
    last: Placement | None = None
    bodies: list[tuple[FloatArray, np.ndarray]] = []
    for px, world, vis in zip(
        clip.image_px[name], clip.world_m[name], clip.visibility[name], strict=True
    ):
        if not np.isfinite(world).all():
            bodies.append((np.full((25, 3), np.nan), np.zeros(25, dtype=np.uint8)))
            continue
        body = body_from_landmarks(
            undistorted_px(cam, px), world, vis, size, intrinsics, initial=last
        )
        last = body.placement
        bodies.append((body.joints_m.astype(np.float64), body.states))
    return bodies


def start_server(
    entries: dict[str, SensorCalibration], http_port: int, zmq_port: int, log_path: Path
) -> tuple[subprocess.Popen[bytes], IO[bytes]]:
    """``python -m skelfuse server`` on loopback with ``entries`` as its stored calibration
    (``bench/live/server.py``'s, with the cameras' intrinsics and lags); it ends with this
    process even when this one is killed outright (``skelfuse/parent_watch.py``)."""
    data_dir = Path(tempfile.mkdtemp(prefix="skelfuse-mono-data-"))
    CalibrationStore(data_dir).save(entries, note="bench/mono/accuracy.py")
    fusion_config = os.environ.get("SKELFUSE_LOAD_FUSION_CONFIG")
    log_file = log_path.open("wb")
    server = subprocess.Popen(
        [sys.executable, "-m", "skelfuse", "--log-level", "WARNING", "server",
         "--http", f"127.0.0.1:{http_port}", "--zmq", f"tcp://127.0.0.1:{zmq_port}",
         "--data", str(data_dir), *(["--fusion-config", fusion_config] if fusion_config else [])],
        stdout=log_file, stderr=subprocess.STDOUT, cwd=ROOT, env=child_environment(),
    )  # fmt: skip
    return server, log_file


def run_live(
    clip: Clip,
    cameras: dict[str, Camera],
    streamed: tuple[str, ...],
    lags: dict[str, float],
    hold_s: float = 1.0,
    tail_s: float = 3.0,
    log_dir: Path | None = None,
) -> LiveRun:
    """Stream ``streamed`` cameras to a fresh server and collect its fused frames.

    Raises:
        RuntimeError: the server or the agents did not come up in time.
    """
    http_port, zmq_port = free_port(), free_port()
    log_dir = log_dir or Path(tempfile.mkdtemp(prefix="skelfuse-mono-"))
    entries = {
        name: SensorCalibration(
            cameras[name].T_world_from_sensor,
            "import:qualisys",
            intrinsics=cameras[name].intrinsics,
            lag_s=lags.get(name, 0.0) / FPS,
        )
        for name in streamed
    }
    server, log_file = start_server(entries, http_port, zmq_port, log_dir / "server.log")
    stop = threading.Event()
    start: list[int] = []
    hold = round(hold_s * FPS)
    threads: list[threading.Thread] = []
    try:
        base = f"http://127.0.0.1:{http_port}"
        wait_for(lambda: http_json(base + "/api/health"), 60.0, "the server")
        for name in streamed:
            source = LandmarkSource(camera_bodies(clip, cameras[name], name), hold, start)
            thread = threading.Thread(
                target=run_agent, args=(name, source, f"tcp://127.0.0.1:{zmq_port}"),
                kwargs={"stop": stop}, daemon=True,
            )  # fmt: skip
            thread.start()
            threads.append(thread)

        def registered() -> bool:
            rows = http_json(base + "/api/sensors")["sensors"]
            return {r["id"] for r in rows if r["connected"]} >= set(streamed)

        wait_for(registered, 30.0, "the agents")
        return _fused_frames(base, clip, hold, start, tail_s)
    finally:
        stop.set()
        for thread in threads:
            thread.join(timeout=5.0)
        server.terminate()
        try:
            server.wait(timeout=10.0)
        except Exception:
            server.kill()
        log_file.close()


def _fused_frames(base: str, clip: Clip, hold: int, start: list[int], tail_s: float) -> LiveRun:
    """Start the agents' clock (``start`` gets the first frame's time, ns since the epoch,
    half a second from now) and collect the fused frames until the clip has played (``hold``
    frames held before it, ``tail_s`` s of grace after it)."""
    frames = len(next(iter(clip.image_px.values())))
    t0_ns = time.time_ns() + 500_000_000
    clip_start_s = t0_ns / 1e9 + hold / FPS
    last_s = clip_start_s + (frames - 1) / FPS
    times: list[float] = []
    joints: list[FloatArray] = []
    persons: list[float] = []
    run = LiveRun(np.zeros(0), np.zeros((0, 25, 3)), np.zeros(0))
    with SyncFeedClient(base) as feed:
        start.append(t0_ns)
        # The server publishes only while frames come: once the clip has played, a
        # watchdog closes the feed, which ends the loop below.
        watchdog = threading.Timer(last_s + tail_s - time.time(), feed.close)
        watchdog.start()
        for frame in feed:
            if frame.t >= last_s - 1e-3:
                break
            if frame.t < clip_start_s - 0.2:
                continue
            times.append((frame.t - clip_start_s) * FPS)
            persons.append(float(len(frame.persons)))
            if not frame.persons:
                joints.append(np.full((25, 3), np.nan))
                continue
            best = max(frame.persons, key=lambda p: len(p.sources))
            joints.append(np.asarray(best.joints, dtype=np.float64))
            for name in best.mirrored:
                run.mirrored[name] = run.mirrored.get(name, 0) + 1
            key = "+".join(sorted(best.sources))
            run.sources[key] = run.sources.get(key, 0) + 1
    watchdog.cancel()
    run.times, run.joints, run.persons = np.array(times), np.array(joints), np.array(persons)
    return run
