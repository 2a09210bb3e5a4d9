"""Network faults and traceable data for integration tests: a pausable TCP proxy on loopback and
a sensor source whose bodies say when they were captured.

Not fixtures: tests build and close these themselves.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time

import numpy as np

from skelfuse.agent.sim.performer import standing_pose
from skelfuse.agent.sources.base import Capture, wait_for_due
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body


class PausableProxy:
    """A TCP proxy (127.0.0.1:``port`` → ``target``) whose forwarding can be paused.

    Paused, it stops reading in both directions: bytes wait in the kernel's socket buffers and
    the sender's queues, as on a network that stalls without closing connections (a Wi-Fi
    drop, a switch rebooting). Resumed, everything queued flows on. Runs its own event loop in
    a daemon thread; :meth:`close` stops it.
    """

    def __init__(self, target_host: str, target_port: int) -> None:
        self._target = (target_host, target_port)
        self._loop = asyncio.new_event_loop()
        self._flowing: asyncio.Event | None = None
        self._ready = threading.Event()
        self.port = 0
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        if not self._ready.wait(5):
            raise RuntimeError("proxy did not start")

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        self._flowing = asyncio.Event()
        self._flowing.set()
        server = self._loop.run_until_complete(asyncio.start_server(self._accept, "127.0.0.1", 0))
        self.port = server.sockets[0].getsockname()[1]
        self._ready.set()
        try:
            self._loop.run_forever()
        finally:
            server.close()
            self._loop.close()

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection(*self._target)
        except OSError:
            writer.close()
            return
        await asyncio.gather(
            self._pump(reader, up_writer), self._pump(up_reader, writer), return_exceptions=True
        )

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert self._flowing is not None
        try:
            while True:
                await self._flowing.wait()
                data = await reader.read(4096)
                if not data:
                    break
                # A pause while this chunk was in hand holds it too.
                await self._flowing.wait()
                writer.write(data)
                await writer.drain()
        finally:
            with contextlib.suppress(Exception):
                writer.close()

    def pause(self) -> None:
        """Stop forwarding (connections stay open)."""
        self._loop.call_soon_threadsafe(self._set_flowing, False)

    def resume(self) -> None:
        """Forward again, queued bytes first."""
        self._loop.call_soon_threadsafe(self._set_flowing, True)

    def _set_flowing(self, on: bool) -> None:
        assert self._flowing is not None
        if on:
            self._flowing.set()
        else:
            self._flowing.clear()

    def close(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)


TIME_CODE_SPEED_M_PER_S = 0.2
"""How fast the time-code body walks along +X: its pelvis x says when it was captured."""


class TimeCodeSource:
    """A 30 fps source of one standing body whose x position encodes its capture time.

    The body stands at ``x = (t_capture − t0) · 0.2 m/s − 1.5 m`` in the sensor frame (identity
    pose hint, so world = sensor frame): interpolating two frames interpolates the time code, so
    any fused view tells when the data it shows was captured (:meth:`captured_at`, ±0.5 ms at
    the feed's 0.1 mm rounding).
    """

    def __init__(self, t0_s: float, fps: float = 30.0) -> None:
        self.t0_s = t0_s
        self._period_s = 1.0 / fps
        self._fps = fps
        self._next_s = time.time()
        self._template = standing_pose().astype(np.float32) + np.array([0, 0, 3], np.float32)

    @property
    def sensor_type(self) -> str:
        return "sim"

    @property
    def fps(self) -> float:
        return self._fps

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return np.eye(4), "manual"

    def next_capture(self, timeout_s: float) -> Capture | None:
        if not wait_for_due(round(self._next_s * 1e9), time.time_ns(), timeout_s, time.sleep):
            return None
        self._next_s = max(self._next_s + self._period_s, time.time() - self._period_s)
        now_ns = time.time_ns()
        joints = self._template.copy()
        joints[:, 0] += np.float32(self.x_at(now_ns / 1e9))
        states = np.full(JOINT_COUNT, TrackingState.TRACKED, np.uint8)
        return Capture(now_ns, (Body(1, joints, states),))

    def x_at(self, t_s: float) -> float:
        return (t_s - self.t0_s) * TIME_CODE_SPEED_M_PER_S - 1.5

    def captured_at(self, pelvis_x_m: float) -> float:
        """Capture time (Unix seconds) of data whose pelvis is at ``pelvis_x_m``."""
        pelvis_x0 = float(self._template[0, 0])
        return self.t0_s + (pelvis_x_m - pelvis_x0 + 1.5) / TIME_CODE_SPEED_M_PER_S

    def close(self) -> None:
        pass
