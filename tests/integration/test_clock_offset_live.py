"""Agents on the server's own machine, with their clocks set off by known amounts: the server's
round-trip offsets come out within a few milliseconds of the truth. Before the agent read its
source in a thread of its own (agent/capture_thread.py), a heartbeat waited for the sensor's
next frame before it was echoed, and each sensor's offset came out short by half that wait
(0–16 ms at 30 fps, the same at every sample)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from tests.integration.conftest import AgentThread, LiveServer
from tests.support import wait_until

pytestmark = pytest.mark.timeout(60)

TRUE_OFFSETS_S = {"cam-a": 0.0, "cam-b": -0.25, "cam-c": 1.5}
"""server − agent: an agent whose clock is ahead by x has offset −x."""
TOLERANCE_S = 0.004


def sensors(live: LiveServer) -> dict[str, dict[str, Any]]:
    rows = httpx.get(live.http_url + "/api/sensors", timeout=5).json()["sensors"]
    return {row["id"]: row for row in rows}


def test_round_trip_offsets_are_within_a_few_ms_of_the_truth(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    positions = [(0.0, 1.0, 3.0), (2.6, 1.0, -1.5), (-2.6, 1.0, -1.5)]
    for (sensor_id, offset_s), position in zip(TRUE_OFFSETS_S.items(), positions, strict=True):
        agent_factory(
            live_server.zmq_url, sensor_id, position, clock_offset_ns=round(-offset_s * 1e9)
        )

    def all_round_trip() -> bool:
        rows = sensors(live_server)
        return len(rows) == 3 and all(r["clock_source"] == "round_trip" for r in rows.values())

    assert wait_until(all_round_trip, 15), sensors(live_server)
    time.sleep(5.0)  # ten heartbeats each: the quickest samples are in the estimate
    measured = {s: row["clock_offset_s"] for s, row in sensors(live_server).items()}
    errors_ms = {s: round((measured[s] - TRUE_OFFSETS_S[s]) * 1e3, 2) for s in TRUE_OFFSETS_S}
    assert all(abs(e) <= TOLERANCE_S * 1e3 for e in errors_ms.values()), errors_ms
