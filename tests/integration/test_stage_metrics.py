"""The live server times every stage of its path (server/stage_timing.py): real uvicorn, real
ZeroMQ ingest, two simulated agents, and the histograms read back from ``/metrics``."""

from __future__ import annotations

from collections.abc import Callable

import httpx

from bench.live.stages import parse_stages
from tests.integration.conftest import AgentThread, LiveServer
from tests.support import wait_until


def test_ingest_fusion_publish_and_lag_are_timed(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    agent_factory(live_server.zmq_url, "cam-a", (0.0, 1.0, 3.0), depth=False)
    agent_factory(live_server.zmq_url, "cam-b", (2.6, 1.0, -1.5), depth=False)
    url = live_server.http_url
    assert wait_until(lambda: httpx.get(url + "/api/health").json()["fused_frames"] > 20, 20)
    fused_before = httpx.get(url + "/api/health").json()["fused_frames"]
    received = sum(s["frames_received"] for s in httpx.get(url + "/api/sensors").json()["sensors"])
    stages = parse_stages(httpx.get(url + "/metrics/").text)
    fused_after = httpx.get(url + "/api/health").json()["fused_frames"]
    counts = {stage: buckets[-1][1] for stage, buckets in stages.items()}
    # Every handled message (frames, hellos, heartbeats) and every fused frame is timed; the
    # server handles requests and messages on one loop, so the reads bracket the counts.
    assert counts["ingest"] >= received > 0
    assert counts["fusion"] == counts["publish"] == counts["lag"]
    assert fused_before <= counts["fusion"] <= fused_after
    # A fused instant waits for the sensors' next frame, so fusion starts after it: most lags
    # are well over the first bucket (25 µs), whatever the machine.
    lag = dict(stages["lag"])
    assert lag[25e-6] <= 0.5 * counts["lag"]
