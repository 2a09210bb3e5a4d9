"""ICP calibration does not stop the server: the real uvicorn server, simulated agents over
ZeroMQ, an ``icp`` run through REST, and the server's own event-loop lag monitor (``/metrics``).

open3d keeps the GIL while it computes; run in a thread of the server, ICP stalled the event loop
again and again (here 0.05–0.8 s at a time, depending on the machine's load; 2.3–5.4 s in issue
11). The solvers now run in a worker process. The agents are processes of their own, as on a rig
(in this process their depth rendering would take its GIL too). On a shared 2-core machine the
idle server itself stalls now and then (the process waits for a core), so the check is the rate
of stalls over 50 ms while ICP runs against the idle rate just before;
bench/live/calibration_stall.py reports the figures.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from skelfuse.calibration.errors import IcpUnavailable
from skelfuse.calibration.open3d_loader import load_open3d
from skelfuse.calibration.rigid import pose_error
from skelfuse.demo import sensor_layout
from tests.integration.conftest import LiveServer
from tests.support import wait_until

pytestmark = pytest.mark.timeout(150)

MAX_STALL_S = 0.05
MAX_EXTRA_STALLS_PER_S = 0.4
"""Stalls over :data:`MAX_STALL_S` per second while ICP runs, beyond the idle server's rate just
before: with ICP in a thread 0.9–1.1 at load 3–4 here (none over 200 ms then, 9 at load 9.7),
with the worker process 0."""
SENSORS = 3
NEAR_TRUTH_DEG_MM = (2.0, 45.0)
"""ICP's result against the true poses it started from: within its own spread (docs/benchmarks.md,
Calibration: skeleton→ICP p95 1.03° / 45 mm). From the truth it usually stays within 0.1° /
5 mm (6 runs here), but CI at 8a604f9 saw one sensor 1.38° off, with 1.0° / 30 mm the bound
then (the clouds hold a walking person; not investigated further)."""


@dataclass(frozen=True)
class Lag:
    """The server's event-loop lag figures at one moment (``/metrics``) and when they were read."""

    read_s: float
    ticks: int
    stalls: int
    """Ticks later than :data:`MAX_STALL_S`."""
    stalled_s: float
    """The lateness of all ticks, summed."""


def loop_lag(url: str) -> Lag:
    text = httpx.get(url + "/metrics/").text
    read_s = time.monotonic()
    samples = {
        (sample.name, sample.labels.get("le")): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
        if sample.name.startswith("skelfuse_event_loop_lag_seconds")
    }
    buckets = {float(le): v for (name, le), v in samples.items() if name.endswith("_bucket")}
    total = buckets[float("inf")]
    stalls = total - buckets[MAX_STALL_S]
    stalled_s = samples[("skelfuse_event_loop_lag_seconds_sum", None)]
    return Lag(read_s, int(total), int(stalls), stalled_s)


@pytest.fixture
def agents(live_server: LiveServer) -> Iterator[list[subprocess.Popen[bytes]]]:
    """Simulated agents (one person walking, depth, true pose hints) as subprocesses."""
    python = [sys.executable, "-m", "skelfuse", "--log-level", "WARNING", "agent", "--source"]
    processes = []
    for sensor_id, pose in sensor_layout(SENSORS):
        args = ["sim", "--id", sensor_id, f"--pose={pose}", "--persons", "1"]
        processes.append(subprocess.Popen([*python, *args, "--server", live_server.zmq_url]))
    yield processes
    for process in processes:
        process.terminate()
    for process in processes:
        process.wait(timeout=10)


def test_icp_calibration_keeps_the_event_loop_running(
    live_server: LiveServer, agents: list[subprocess.Popen[bytes]]
) -> None:
    try:
        load_open3d()
    except IcpUnavailable as exc:
        pytest.skip(f"open3d cannot load here, so no ICP runs: {exc}")
    url = live_server.http_url

    def hinted_poses() -> dict[str, np.ndarray]:
        rows = httpx.get(url + "/api/sensors").json()["sensors"]
        return {
            r["id"]: np.asarray(r["calibration"]["T_world_from_sensor"])
            for r in rows
            if r["connected"] and r["calibration"]["T_world_from_sensor"] is not None
        }

    assert wait_until(lambda: len(hinted_poses()) == SENSORS, timeout_s=60)
    truth = hinted_poses()  # the sim agents' true poses
    idle = loop_lag(url)
    time.sleep(3.0)
    idle_end = loop_lag(url)  # how often this machine stalls the server with nothing to do
    idle_rate = (idle_end.stalls - idle.stalls) / (idle_end.read_s - idle.read_s)
    response = httpx.post(url + "/api/calibration/runs", json={"method": "icp"})
    assert response.status_code == 202, response.text
    run = response.json()
    solving: Lag | None = None
    deadline = time.monotonic() + 120
    while run["state"] in ("capturing", "solving") and time.monotonic() < deadline:
        if run["state"] == "solving" and solving is None:
            solving = loop_lag(url)
        time.sleep(0.05)
        run = httpx.get(f"{url}/api/calibration/runs/{run['id']}").json()
    done = loop_lag(url)
    assert run["state"] == "done", run
    # The run's result, as from a thread: ICP ran on every sensor and kept near the truth.
    ids = sorted(truth)
    for sensor_id in ids[1:]:
        result = run["results"][sensor_id]
        assert "icp_applied" in result["metrics"], result
        pose = np.asarray(result["T_world_from_sensor"])
        estimate = np.linalg.inv(np.asarray(run["results"][ids[0]]["T_world_from_sensor"])) @ pose
        rotation_deg, translation_mm = pose_error(
            estimate, np.linalg.inv(truth[ids[0]]) @ truth[sensor_id]
        )
        max_deg, max_mm = NEAR_TRUTH_DEG_MM
        assert rotation_deg < max_deg and translation_mm < max_mm, (sensor_id, result)
    assert run["floor"]["source"] == "depth"
    assert solving is not None and done.ticks - solving.ticks > 100  # the monitor ticked
    window = done.read_s - solving.read_s
    rate = (done.stalls - solving.stalls) / window
    assert rate <= idle_rate + MAX_EXTRA_STALLS_PER_S, (
        f"{done.stalls - solving.stalls} event-loop stalls over {MAX_STALL_S * 1000:.0f} ms in "
        f"{window:.1f} s of ICP ({rate:.2f}/s; idle {idle_rate:.2f}/s)"
    )
