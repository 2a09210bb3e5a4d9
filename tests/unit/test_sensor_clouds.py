"""Viewers' depth clouds (server/depth_clouds.py ``LatestClouds``, server/routes_sensors.py):
one request per sensor in flight, a young cloud shared, a refusal remembered as long, a larger
request asked again, the agent's stamp mapped to the server clock; the cloud's JSON encoded in
chunks gives the same text as at once. Time is a fake clock."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import numpy as np
import orjson
import pytest

from skelfuse.protocol.depth_cloud import encode_reply
from skelfuse.server.depth_clouds import LatestClouds
from skelfuse.server.errors import AgentRequestFailed, CloudUnavailable
from skelfuse.server.routes_sensors import ENCODE_CHUNK, _points_json


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def time(self) -> float:
        return 1_763_712_000.0 + self.now

    def monotonic(self) -> float:
        return self.now

    async def sleep(self, seconds: float) -> None:
        self.now += seconds


class Agents:
    """Answers after ``gate`` opens: a cloud of ``max_points`` points, or ``error``."""

    def __init__(self) -> None:
        self.asked: list[tuple[str, int]] = []
        self.gate = asyncio.Event()
        self.error: Exception | None = None

    async def request(
        self, sensor_id: str, method: str, params: dict[str, Any], timeout_s: float
    ) -> Any:
        self.asked.append((sensor_id, params["max_points"]))
        await self.gate.wait()
        if self.error is not None:
            raise self.error
        points = np.random.default_rng(len(self.asked)).uniform(-2, 2, (params["max_points"], 3))
        return encode_reply(points, t_capture_ns=5_000_000_000)


async def test_callers_share_one_request_and_a_young_cloud() -> None:
    clock, agents = Clock(), Agents()
    clouds = LatestClouds(agents, lambda _: 2.5, clock)
    waiting = [asyncio.create_task(clouds.cloud("cam-a", 300)) for _ in range(5)]
    await asyncio.sleep(0)
    agents.gate.set()
    got = await asyncio.gather(*waiting)
    assert agents.asked == [("cam-a", 300)]
    assert all(g is got[0] for g in got) and len(got[0].points) == 300
    assert got[0].t_capture_s == pytest.approx(5.0 + 2.5)  # agent stamp + server - agent offset
    clock.now += 0.4
    assert await clouds.cloud("cam-a", 100) is got[0]  # young, and asked with more points
    assert len(got[0].at_most(100)) == 100
    await clouds.cloud("cam-a", 1000)  # more points than the young cloud was asked with
    clock.now += 0.6
    await clouds.cloud("cam-a", 100)  # old
    assert agents.asked == [("cam-a", 300), ("cam-a", 1000), ("cam-a", 100)]


async def test_a_refusal_is_a_503_remembered_as_long_as_a_cloud() -> None:
    clock, agents = Clock(), Agents()
    agents.gate.set()
    agents.error = AgentRequestFailed("sensor 'cam-a' refused 'depth_cloud': no depth")
    clouds = LatestClouds(agents, lambda _: None, clock)
    for _ in range(3):
        with pytest.raises(CloudUnavailable, match="no depth"):
            await clouds.cloud("cam-a", 300)
    assert len(agents.asked) == 1
    clock.now += 0.6
    agents.error = None
    assert len((await clouds.cloud("cam-a", 300)).points) == 300
    assert len(agents.asked) == 2


@pytest.mark.parametrize("count", [0, 1, ENCODE_CHUNK - 1, ENCODE_CHUNK, 2 * ENCODE_CHUNK + 7])
async def test_chunked_points_are_the_same_json_as_at_once(count: int) -> None:
    points = np.round(np.random.default_rng(count).uniform(-4, 4, (count, 3)), 3)
    text = await _points_json(points)
    assert text == orjson.dumps(points, option=orjson.OPT_SERIALIZE_NUMPY)
    assert json.loads(text) == points.tolist()
