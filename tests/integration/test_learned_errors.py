"""Each sensor's learned error as apps and the rig's setter see it, with a real uvicorn server and
three simulated agents over ZeroMQ fusing one simulated person: ``/api/sensors``'s
``learned_error`` per sensor, the ``/metrics`` gauges, and a sensor whose pose a calibration
import changes re-learned from its prior while the others keep what they learned."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from skelfuse.fusion.settings import LearningSettings
from tests.integration.conftest import AgentThread, LiveServer
from tests.integration.test_calibration_api import POSITIONS
from tests.support import wait_until

pytestmark = pytest.mark.timeout(150)
SENSORS = ("cam-a", "cam-b", "cam-c")
GROUPS = ("trunk", "arms", "legs")
PRIOR_SAMPLES = LearningSettings().prior_samples
MOST_MM = 500.0
"""No simulated Kinect view is this far off on average (its prior is tens of mm)."""


def sensor_rows(url: str) -> dict[str, dict[str, Any]]:
    answer = httpx.get(url + "/api/sensors", timeout=10).json()
    return {row["id"]: row for row in answer["sensors"]}


def all_learned(url: str) -> dict[str, dict[str, Any]] | None:
    """Every sensor's learned error once fusion's evidence outweighs every prior, else None."""
    rows = sensor_rows(url)
    errors = {s: rows[s]["learned_error"] for s in SENSORS if s in rows}
    if len(errors) < len(SENSORS) or any(e is None or not e["learned"] for e in errors.values()):
        return None
    return errors


def fusing_rig(
    live: LiveServer, agent_factory: Callable[..., AgentThread]
) -> dict[str, dict[str, Any]]:
    """Three agents seeing one person (their poses from their hints) until all are learned."""
    for sensor_id in SENSORS:
        agent_factory(live.zmq_url, sensor_id, POSITIONS[sensor_id])
    learned: list[dict[str, dict[str, Any]]] = []

    def done() -> bool:
        errors = all_learned(live.http_url)
        if errors is not None:
            learned.append(errors)
        return errors is not None

    assert wait_until(done, timeout_s=60, interval_s=0.3), sensor_rows(live.http_url)
    return learned[-1]


def test_sensors_and_metrics_show_each_sensors_learned_error(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    errors = fusing_rig(live_server, agent_factory)
    for sensor_id, error in errors.items():
        assert set(error) == {"trunk_mm", "arms_mm", "legs_mm", "samples", "learned"}, error
        for group in GROUPS:
            mm = error[f"{group}_mm"]
            assert math.isfinite(mm) and 0 < mm < MOST_MM, (sensor_id, error)
        assert error["samples"] >= PRIOR_SAMPLES, (sensor_id, error)

    text = httpx.get(live_server.http_url + "/metrics/", timeout=10).text
    families = {f.name: f for f in text_string_to_metric_families(text)}
    gauge = families["skelfuse_sensor_learned_error_mm"]
    assert gauge.type == "gauge"
    shown = {(s.labels["sensor"], s.labels["group"]): s.value for s in gauge.samples}
    assert set(shown) == {(s, g) for s in SENSORS for g in GROUPS}, shown
    assert all(0 < mm < MOST_MM for mm in shown.values()), shown
    samples = {
        s.labels["sensor"]: s.value
        for s in families["skelfuse_sensor_learned_error_samples"].samples
    }
    assert set(samples) == set(SENSORS) and min(samples.values()) >= PRIOR_SAMPLES, samples


def test_an_imported_calibration_that_moves_a_sensor_restarts_its_learning(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    url = live_server.http_url
    fusing_rig(live_server, agent_factory)
    pose = np.array(sensor_rows(url)["cam-a"]["calibration"]["T_world_from_sensor"])
    pose[0, 3] += 0.01  # cam-a moved 1 cm; cam-b and cam-c keep the poses their agents hint
    body = {"format": 1, "sensors": {"cam-a": {"T_world_from_sensor": pose.tolist()}}}
    imported = httpx.post(url + "/api/calibration/import", json=body, timeout=10)
    assert imported.status_code == 200, imported.text
    # Since the import cam-a has gathered evidence for as long as the others, which kept
    # theirs: it has less than either whenever it is read.
    rows = sensor_rows(url)
    assert rows["cam-a"]["calibration"]["state"] == "stored", rows["cam-a"]
    moved = rows["cam-a"]["learned_error"]["samples"]
    kept = [rows[s]["learned_error"]["samples"] for s in ("cam-b", "cam-c")]
    assert moved < min(kept), (moved, kept)
    assert min(kept) >= PRIOR_SAMPLES, kept
