"""A sensor's calibrated clock lag (``lag_s``) applied by a real server on loopback, with real
agents over ZeroMQ: three simulated sensors at the same place see the same person sway; two of
them stamp their frames 40 ms after what they show (a camera whose frames are stamped late, its
heartbeats on time, so the round-trip clock offset cannot absorb the lag). The one whose stored
calibration says ``lag_s = 0.04`` lines up with the undelayed one; the one without does not,
until a calibration imported at run time gives it the lag too."""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.runner import run_agent
from skelfuse.agent.sim.performer import standing_pose
from skelfuse.agent.sources.base import Capture
from skelfuse.agent.sources.sim import SimSource
from skelfuse.calibration.store import CalibrationStore, SensorCalibration
from skelfuse.client.sync import SyncFeedClient
from skelfuse.protocol.transform import look_at_pose
from skelfuse.server.settings import Settings
from tests.integration.conftest import LiveServer, start_server
from tests.support import free_port, wait_until

pytestmark = pytest.mark.timeout(120)

LAG_S = 0.04
POSE = look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0))
SWAY_M, SWAY_PERIOD_S = 0.8, 2.0  # mean speed 4 * 0.8 / 2 = 1.6 m/s: 6.4 cm in 40 ms


class Swaying:
    """One person swaying sideways (x) in front of the sensors, the same at every instant for
    every sensor."""

    person_count = 1

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        shift = SWAY_M * math.sin(2 * math.pi * t_s / SWAY_PERIOD_S)
        joints: npt.NDArray[np.float64] = standing_pose() + np.array([shift, 0.0, 0.0])
        return joints[None]


class LateStamps(SimSource):
    """Frames stamped ``LAG_S`` after the instant they show; heartbeats on the true clock."""

    def capture_at(self, true_ns: int) -> Capture:
        capture = super().capture_at(true_ns)
        return dataclasses.replace(capture, t_capture_ns=capture.t_capture_ns + round(LAG_S * 1e9))


@pytest.fixture
def lagged_rig(tmp_path: Path) -> Iterator[LiveServer]:
    """A server whose stored calibration puts cam-a, cam-b and cam-c at the same pose, cam-b
    with ``lag_s`` = 40 ms, and their three agents streaming (cam-b and cam-c stamp late)."""
    data_dir = tmp_path / "data"
    CalibrationStore(data_dir).save(
        {
            "cam-a": SensorCalibration(POSE, "test"),
            "cam-b": SensorCalibration(POSE, "test", lag_s=LAG_S),
            "cam-c": SensorCalibration(POSE, "test"),
        }
    )
    http, zmq = free_port(), free_port()
    live = start_server(
        Settings(
            http_host="127.0.0.1",
            http_port=http,
            zmq_endpoint=f"tcp://127.0.0.1:{zmq}",
            data_dir=data_dir,
        )
    )
    stop = threading.Event()
    threads = []
    for seed, (sensor_id, kind) in enumerate(
        (("cam-a", SimSource), ("cam-b", LateStamps), ("cam-c", LateStamps)), start=1
    ):
        source = kind(Swaying(), POSE, seed=seed, send_pose_hint=False, hand_states=False)
        thread = threading.Thread(
            target=run_agent, args=(sensor_id, source, live.zmq_url), kwargs={"stop": stop},
            daemon=True,
        )  # fmt: skip
        thread.start()
        threads.append(thread)
    try:
        yield live
    finally:
        stop.set()
        for thread in threads:
            thread.join(timeout=10)
        live.stop()


def on_round_trip_clocks(live: LiveServer) -> bool:
    rows = httpx.get(live.http_url + "/api/sensors", timeout=5).json()["sensors"]
    return len(rows) == 3 and all(
        r["connected"] and r["clock_source"] == "round_trip" for r in rows
    )


def delays(live: LiveServer, frames: int, after_s: float = 0.0) -> dict[str, float]:
    """How late each sensor's view shows the sway (seconds) over ``frames`` fused frames (those
    fused after ``after_s``, server clock = this machine's clock on loopback): the least-squares
    fit of its x offset from the true pose, ``bias - delay * speed``, so a sensor's own constant
    error does not count and its lateness does."""
    columns: dict[str, list[tuple[float, float]]] = {s: [] for s in ("cam-a", "cam-b", "cam-c")}
    truth = standing_pose()[:, 0]
    seen: Counter[tuple[str, ...]] = Counter()
    with SyncFeedClient(live.http_url, raw=True, reconnect=False) as feed:
        for frame in feed:
            views = {body.sensor: body.joints for body in frame.raw}
            seen[tuple(sorted(views))] += 1
            # Bounded: a feed that stops showing some sensor fails here, saying which.
            assert seen.total() <= 4 * frames, f"frames by the sensors in them: {dict(seen)}"
            if frame.t <= after_s or set(views) != set(columns):
                continue
            phase = 2 * math.pi * frame.t / SWAY_PERIOD_S
            shift = SWAY_M * math.sin(phase)
            speed = SWAY_M * 2 * math.pi / SWAY_PERIOD_S * math.cos(phase)
            for sensor, rows in columns.items():
                rows.append((speed, float(np.nanmean(views[sensor][:, 0] - truth - shift))))
            if len(columns["cam-a"]) >= frames:
                break
    fitted = {}
    for sensor, rows in columns.items():
        speed_x = np.array(rows)
        design = np.column_stack([np.ones(len(rows)), -speed_x[:, 0]])
        (_, delay), *_ = np.linalg.lstsq(design, speed_x[:, 1], rcond=None)
        fitted[sensor] = float(delay)
    return fitted


def test_a_stored_lag_lines_a_late_sensor_up_and_a_run_time_import_reaches_it(
    lagged_rig: LiveServer,
) -> None:
    live = lagged_rig
    assert wait_until(lambda: on_round_trip_clocks(live), timeout_s=30), httpx.get(
        live.http_url + "/api/sensors"
    ).json()
    rows = httpx.get(live.http_url + "/api/sensors", timeout=5).json()["sensors"]
    assert {r["id"]: r["clock_lag_s"] for r in rows} == {"cam-a": 0.0, "cam-b": LAG_S, "cam-c": 0.0}
    # A full sway period (60 frames at 30 Hz) and then some, so the bias and the speed separate.
    before = delays(live, 90)
    # Without the lag, cam-c shows the person where cam-a showed it 40 ms earlier (measured
    # 32-35 ms later than cam-a at load 7: the fit's noise; the lagged ones within 4 ms).
    assert before["cam-c"] - before["cam-a"] > LAG_S / 2, before
    assert abs(before["cam-b"] - before["cam-a"]) < 0.012, before

    exported: dict[str, Any] = httpx.get(live.http_url + "/api/calibration/export").json()
    exported["sensors"]["cam-c"]["lag_s"] = LAG_S
    imported = httpx.post(live.http_url + "/api/calibration/import", json=exported, timeout=10)
    assert imported.status_code == 200, imported.text
    rows = httpx.get(live.http_url + "/api/sensors", timeout=5).json()["sensors"]
    assert {r["id"]: r["clock_lag_s"] for r in rows}["cam-c"] == LAG_S
    # Frames fused from now on: the buffered frames move with the import, so no settling time.
    after = delays(live, 90, after_s=time.time())
    assert abs(after["cam-c"] - after["cam-a"]) < 0.012, (before, after)
    assert abs(after["cam-b"] - after["cam-a"]) < 0.012, (before, after)
