"""Recording over REST with real agents, then offline replay and a live replay agent.

While a recording runs, ``FusionHub.handle_message`` hands accepted hellos and frames to the
recorder (``FusionHub.start_tap``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from skelfuse.agent.runner import run_agent
from skelfuse.agent.sources.replay import ReplaySource
from skelfuse.protocol.recording_file import read_recording
from skelfuse.recording.replay import replay
from tests.integration.conftest import AgentThread, LiveServer
from tests.support import wait_until

pytestmark = pytest.mark.timeout(90)


def test_record_stop_list_download_replay(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread], tmp_path: Path
) -> None:
    base = live_server.http_url + "/api/recordings"
    agent_factory(live_server.zmq_url, "cam-a", (0.0, 1.0, 3.0), 2)
    agent_factory(live_server.zmq_url, "cam-b", (2.6, 1.0, -1.5), 2)
    assert wait_until(
        lambda: httpx.get(live_server.http_url + "/api/health").json()["persons"] >= 1, 20
    )
    started = httpx.post(base, json={"name": "two cams"}, timeout=5)
    assert started.status_code == 201, started.text
    recording_id = started.json()["id"]
    assert started.json()["state"] == "recording"
    assert httpx.post(base, json={}, timeout=5).status_code == 409
    time.sleep(2.5)
    listed = httpx.get(base, timeout=5).json()["recordings"]
    assert listed[0]["id"] == recording_id and listed[0]["state"] == "recording"
    stopped = httpx.post(f"{base}/{recording_id}/stop", timeout=10).json()
    assert stopped["state"] == "complete" and stopped["duration_s"] > 2.0
    assert sorted(stopped["sensors"]) == ["cam-a", "cam-b"]
    assert httpx.post(f"{base}/{recording_id}/stop", timeout=5).status_code == 404
    entry = httpx.get(base, timeout=5).json()["recordings"][0]
    assert entry["state"] == "complete" and entry["size_bytes"] > 10_000

    download = httpx.get(f"{base}/{recording_id}/download", timeout=10)
    assert download.status_code == 200
    path = tmp_path / "take.sfrec"
    path.write_bytes(download.content)
    _header, records = read_recording(path, strict=True)
    kinds = {(r.sensor_id, r.kind) for r in records}
    assert {("cam-a", "hello"), ("cam-b", "hello"), ("cam-a", "frame")} <= kinds
    fused = list(replay(path))
    assert len(fused) > 30 and any(len(f.persons) == 2 for f in fused[-10:])
    assert httpx.get(f"{base}/nope/download", timeout=5).status_code == 404

    # Play one recorded sensor back live, as if it were connected.
    source = ReplaySource(path, "cam-a")
    stop = threading.Event()
    thread = threading.Thread(
        target=run_agent,
        args=("cam-a-replay", source, live_server.zmq_url),
        kwargs={"stop": stop},
        daemon=True,
    )
    thread.start()

    def replayed() -> dict[str, object]:
        rows = httpx.get(live_server.http_url + "/api/sensors", timeout=5).json()["sensors"]
        return next((row for row in rows if row["id"] == "cam-a-replay"), {})

    try:
        # Playback starts once the server has registered the agent: every recorded frame
        # arrives, the first ones too (before, a slow registration lost the start of the take).
        assert wait_until(lambda: replayed().get("frames_received") == source.frame_count, 30), (
            source.frame_count,
            replayed(),
        )
        assert replayed()["type"] == "replay"
    finally:
        stop.set()
        thread.join(timeout=10)
