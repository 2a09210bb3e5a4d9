"""The agent's main loop: read the source, send frames, keep the link alive."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from skelfuse import __version__
from skelfuse.agent.capture_thread import CaptureThread
from skelfuse.agent.link import AgentLink, CurveKeys, RequestHandler
from skelfuse.agent.sources.base import SkeletonSource
from skelfuse.protocol.wire import Frame, Hello

logger = logging.getLogger(__name__)


def make_hello(sensor_id: str, source: SkeletonSource) -> Hello:
    """The source's registration; a source with a ``pose_space`` registers as moving."""
    hint = source.pose_hint()
    pose_space: str | None = getattr(source, "pose_space", None)
    return Hello(
        sensor_id=sensor_id,
        sensor_type=source.sensor_type,
        agent_version=__version__,
        fps=source.fps,
        t_ns=time.time_ns(),
        pose_hint=hint[0] if hint else None,
        pose_hint_source=hint[1] if hint else None,
        moving=pose_space is not None,
        pose_space=pose_space,
    )


def run_agent(
    sensor_id: str,
    source: SkeletonSource,
    server_endpoint: str,
    *,
    stop: threading.Event | None = None,
    duration_s: float | None = None,
    curve: CurveKeys | None = None,
) -> AgentLink:
    """Stream ``source`` to the server until ``stop`` is set or ``duration_s`` has passed.

    Survives server restarts (the link re-registers by itself). Returns the closed link, whose
    ``stats`` say how many frames went out and how many were dropped.
    """
    stop = stop or threading.Event()
    # Sources that can do more than stream (e.g. capture depth) say so with request_handlers().
    handlers: dict[str, RequestHandler] = getattr(source, "request_handlers", dict)()
    # Heartbeats must carry the same clock as the capture stamps (the server's round-trip
    # offset estimate maps one onto the other); sources with their own clock say so.
    clock: Callable[[], int] = getattr(source, "wall_clock_ns", time.time_ns)
    link = AgentLink(
        server_endpoint,
        lambda: make_hello(sensor_id, source),
        handlers=handlers,
        curve=curve,
        wall_clock_ns=clock,
    )
    moving = getattr(source, "pose_space", None) is not None
    deadline = None if duration_s is None else time.monotonic() + duration_s
    seq = 0
    last_report = time.monotonic()

    def running() -> bool:
        return not stop.is_set() and (deadline is None or time.monotonic() < deadline)

    try:
        link.poll()
        # A live sensor is drained from the start (frames before registration are dropped,
        # never queued); a recording would play its beginning to nobody, so it waits.
        if getattr(source, "waits_for_server", False):
            while running() and not link.registered:
                link.poll(timeout_s=0.05)
        # The source is read in its own thread so that a heartbeat is answered when it comes,
        # not after the source's next frame (agent/capture_thread.py says why).
        with CaptureThread(source, name=f"capture-{sensor_id}") as captures:
            while running():
                link.poll(timeout_s=0.1, wake_fd=captures.fileno())
                for capture in captures.take():
                    seq += 1
                    if moving and capture.pose is None:
                        # The server could not place it; the seq gap shows the loss (the pose
                        # source counts and logs why, e.g. agent/poses/posed.py).
                        continue
                    link.send_frame(
                        Frame(
                            seq, capture.t_capture_ns, capture.bodies, capture.floor, capture.pose
                        )
                    )
                if time.monotonic() - last_report > 10.0:
                    last_report = time.monotonic()
                    logger.info(
                        "%s: %d frames sent, %d dropped, registered=%s",
                        sensor_id,
                        link.stats.frames_sent,
                        link.stats.frames_dropped,
                        link.registered,
                    )
    finally:
        link.close()
        source.close()
    return link
