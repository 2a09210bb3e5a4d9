"""``skelfuse demo`` killed outright leaves no server or agent behind (issue 11: both ran on for
2.5 hours after the demo was SIGKILLed). Real processes on loopback: the demo, its server and
its simulated agent."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import free_port, wait_until
from tests.support_proc import children_of, gone_within

pytestmark = pytest.mark.skipif(
    not Path("/proc").is_dir() or os.name != "posix", reason="reads process states from /proc"
)


@pytest.mark.timeout(180)
def test_a_killed_demo_leaves_no_server_or_agent(tmp_path: Path) -> None:
    demo = subprocess.Popen(
        [
            sys.executable, "-m", "skelfuse", "--log-level", "WARNING", "demo",
            "--sensors", "1", "--persons", "1", "--calibration", "truth",
            "--http", f"127.0.0.1:{free_port()}", "--zmq-port", str(free_port()),
            "--data", str(tmp_path / "data"),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    children: list[int] = []
    try:
        # The server first, then (once it answers) the agent.
        assert wait_until(lambda: len(children_of(demo.pid)) >= 2, timeout_s=120, interval_s=0.2), (
            f"the demo did not start its server and agent (exit code {demo.poll()})"
        )
        children = children_of(demo.pid)
    finally:
        demo.send_signal(signal.SIGKILL)  # no cleanup at all, as the OOM killer or a CI kill
        demo.wait()
    # Each child notices within a poll (0.25 s), stops in order, or is ended after 10 s.
    left = [pid for pid in children if not gone_within(pid, 20.0)]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert not left, f"{len(left)} of {len(children)} children outlived the killed demo"
