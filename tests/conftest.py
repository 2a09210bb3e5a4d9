"""Shared fixtures: free loopback ports, the shared data folder, a running demo stack, and the
fusion stages compiled before any test."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skelfuse.cli.values import parse_pose
from skelfuse.demo import sensor_layout
from skelfuse.fusion.engine import warm_up
from skelfuse.protocol.transform import invert, pose_from_position_yaw_pitch
from tests.support import free_port, unavailable, wait_until
from tests.support_terminal import popen_in_terminal

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = PROJECT_ROOT.parent / "shared" / "data"
CMU_DIR = SHARED_DATA / "cmu-mocap"


@pytest.fixture(scope="session", autouse=True)
def _fusion_stages_compiled() -> None:
    """Compile the fusion stages' loops (or load numba's cache) once before any test, as the
    server and replay do at start: a test that times a fusion loop it built itself must not pay
    that inside its first fusion step."""
    warm_up()


@pytest.fixture
def cmu_dir() -> Path:
    """The CMU mocap samples; skips with a visible reason when ../shared/data is absent."""
    if not (CMU_DIR / "scaled_131_01.bvh").is_file():
        unavailable(f"shared mocap data not found at {CMU_DIR}", "CI must provide it")
    return CMU_DIR


# Begins with "-" on purpose: secrets.token_urlsafe gives such a token one time in 64, and the
# demo once passed it to the server as a separate argument, which argparse read as a flag.
DEMO_TOKEN = "-e2e-token"


@dataclass(frozen=True)
class DemoStack:
    http_url: str
    ws_url: str
    zmq_port: int
    sensors: int
    persons: int
    process: subprocess.Popen[bytes]
    log_path: Path
    data_dir: Path
    """The demo's data folder: its CurveZMQ keys (tests check no secret reaches the log)."""

    @property
    def token(self) -> str:
        return DEMO_TOKEN

    @property
    def viewer_url(self) -> str:
        return f"{self.http_url}/?token={DEMO_TOKEN}"

    def get_json(self, path: str) -> dict[str, Any]:
        with urllib.request.urlopen(self.http_url + path, timeout=5) as response:
            data: dict[str, Any] = json.load(response)
            return data

    def T_sim_from_world(self) -> np.ndarray:
        """Maps the calibrated world (which the demo found by itself) into the simulator's
        world, where the ground truth lives, through the reference sensor sim-1."""
        layout = dict(sensor_layout(self.sensors))
        position, yaw, pitch = parse_pose(layout["sim-1"])
        T_sim_from_ref = pose_from_position_yaw_pitch(position, yaw, pitch)
        calibration = self.get_json("/api/calibration")
        T_world_from_ref = np.asarray(calibration["sensors"]["sim-1"]["T_world_from_sensor"])
        result: np.ndarray = T_sim_from_ref @ invert(T_world_from_ref)
        return result


@pytest.fixture(scope="module")
def demo_stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DemoStack]:
    """``skelfuse demo`` exactly as a user runs it (server + 3 sim agents as processes),
    on free loopback ports; stopped with Ctrl-C (SIGINT) at the end."""
    http_port, zmq_port = free_port(), free_port()
    log_path = tmp_path_factory.mktemp("demo") / "demo.log"
    data_dir = log_path.parent / "data"
    # On a terminal, as a person runs it: the demo then shows the viewer's address in full.
    process = popen_in_terminal(
        [sys.executable, "-m", "skelfuse", "demo", "--sensors", "3", "--persons", "2",
         "--http", f"127.0.0.1:{http_port}", "--zmq-port", str(zmq_port), "--duration", "300",
         f"--token={DEMO_TOKEN}", "--data", str(data_dir)],
        log_path, cwd=PROJECT_ROOT,
    )  # fmt: skip
    stack = DemoStack(f"http://127.0.0.1:{http_port}", f"ws://127.0.0.1:{http_port}", zmq_port,
                      3, 2, process, log_path, data_dir)  # fmt: skip

    def fused() -> bool:
        if process.poll() is not None:  # no point waiting two minutes for a demo that has exited
            pytest.fail(f"the demo exited with code {process.returncode}:\n" + log_path.read_text())
        health = stack.get_json("/api/health")
        return health["sensors_online"] == 3 and int(str(health["persons"])) >= 1

    try:
        # The demo calibrates itself first (about 25 s: 15 s of walking, then ICP).
        if not wait_until(fused, timeout_s=120):
            process.send_signal(signal.SIGINT)
            process.wait(timeout=20)
            pytest.fail("the demo did not start fusing within 120 s:\n" + log_path.read_text())
        yield stack
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Under CI (``CI`` set) a skipped test fails the run: CI installs everything the tests
    need (the dev extra, Chromium, Blender, ../shared/data), so a skip there means a test that
    silently did not run. Locally skips stay skips, each with its reason (``-ra``)."""
    if not os.environ.get("CI") or exitstatus != pytest.ExitCode.OK:
        return
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    skipped = reporter.stats.get("skipped", []) if reporter is not None else []
    if skipped:
        if reporter is not None:
            reporter.write_line(
                f"error: {len(skipped)} test(s) skipped under CI, which must run them all",
                red=True,
            )
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
