"""Run by test_mono_source.py inside ``.venv-mono`` (mediapipe, numpy<2): the ``mono`` source on
a video, streamed by the real agent loop to a server's ZeroMQ endpoint, with every Python socket
connect and name lookup refused and counted (the model must load from the wheel; ZeroMQ's own
connection is made by libzmq in C and is unaffected). Prints one JSON line of counts.

    .venv-mono/bin/python tests/integration/mono_agent_child.py VIDEO ENDPOINT SENSOR_ID OUT.npz

OUT.npz gets the joints and states of every body sent, in order.
"""

from __future__ import annotations

import json
import socket
import sys
import threading
import time
from typing import NoReturn

attempts: list[str] = []


def _refuse(*args: object, **kwargs: object) -> NoReturn:
    attempts.append(repr(args[1:] or kwargs)[:200])
    raise OSError("network disabled by the mono source test")


socket.socket.connect = _refuse  # type: ignore[method-assign]
socket.socket.connect_ex = _refuse  # type: ignore[method-assign]
socket.create_connection = _refuse  # type: ignore[assignment]
socket.getaddrinfo = _refuse  # type: ignore[assignment]


def main() -> None:
    import numpy as np

    from skelfuse.agent.runner import run_agent
    from skelfuse.agent.sources.base import Capture
    from skelfuse.agent.sources.mono import MonoSource

    video, endpoint, sensor_id, joints_out = sys.argv[1:5]
    source = MonoSource(video=video, fov_deg=50.0)
    stop = threading.Event()
    sent: list[Capture] = []
    next_capture = source.next_capture

    def recorded(timeout_s: float) -> Capture | None:
        capture = next_capture(timeout_s)
        if capture is not None:
            sent.append(capture)
        return capture

    source.next_capture = recorded  # type: ignore[method-assign]

    def stop_after_the_last_frame() -> None:
        while not source.finished:
            time.sleep(0.02)
        time.sleep(0.5)  # the last frames leave the socket
        stop.set()

    threading.Thread(target=stop_after_the_last_frame, daemon=True).start()
    cpu_start = time.process_time()
    link = run_agent(sensor_id, source, endpoint, stop=stop, duration_s=150.0)
    cpu_s = time.process_time() - cpu_start
    bodies = [c.bodies[0] for c in sent if c.bodies]
    np.savez(
        joints_out,
        joints_m=np.array([b.joints_m for b in bodies]),
        states=np.array([b.states for b in bodies]),
    )
    print(
        json.dumps(
            {
                "frames_read": source.frames_read,
                "frames_with_body": source.frames_with_body,
                "frames_sent": link.stats.frames_sent,
                "frames_dropped": link.stats.frames_dropped,
                "finished": source.finished,
                "network_attempts": attempts,
                "cpu_ms_per_frame": 1000.0 * cpu_s / max(source.frames_read, 1),
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main()
