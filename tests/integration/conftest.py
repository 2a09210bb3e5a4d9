"""A real uvicorn server with the real ZeroMQ ingest, on loopback, in a background thread."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import uvicorn
from websockets.sync.client import connect

from skelfuse.agent.runner import run_agent
from skelfuse.agent.sim.performer import Performer, ProceduralPerformer
from skelfuse.agent.sources.sim import SimSource
from skelfuse.protocol.transform import look_at_pose
from skelfuse.server.app import create_app
from skelfuse.server.settings import Settings
from tests.support import free_port


@dataclass
class LiveServer:
    settings: Settings
    server: uvicorn.Server
    thread: threading.Thread

    @property
    def http_url(self) -> str:
        return f"http://127.0.0.1:{self.settings.http_port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.settings.http_port}"

    @property
    def zmq_url(self) -> str:
        return self.settings.zmq_endpoint

    def stop(self) -> None:
        """Shut the server down and wait until it has released its ports (its thread ends after
        the lifespan closes the ZeroMQ socket): a test that starts another server on the same
        ports must not race the first one's shut-down."""
        self.server.should_exit = True
        self.thread.join(timeout=30)
        if self.thread.is_alive():
            raise RuntimeError("uvicorn did not stop within 30 s: its ports are still bound")


def start_server(settings: Settings) -> LiveServer:
    config = uvicorn.Config(
        create_app(settings), host="127.0.0.1", port=settings.http_port, log_level="warning",
        lifespan="on", ws_max_size=64 * 1024, ws_ping_interval=1.0, ws_ping_timeout=1.0,
    )  # fmt: skip
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 15
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.02)
    return LiveServer(settings, server, thread)


@pytest.fixture
def server_factory(tmp_path: Path) -> Iterator[Callable[..., LiveServer]]:
    started: list[LiveServer] = []
    ports = {"http": free_port(), "zmq": free_port()}

    def make(**overrides: object) -> LiveServer:
        settings = Settings(
            http_host="127.0.0.1", http_port=ports["http"],
            zmq_endpoint=f"tcp://127.0.0.1:{ports['zmq']}", data_dir=tmp_path / "data",
            **overrides,  # type: ignore[arg-type]
        )  # fmt: skip
        live = start_server(settings)
        started.append(live)
        return live

    yield make
    for live in started:
        live.stop()


@pytest.fixture
def live_server(server_factory: Callable[..., LiveServer]) -> LiveServer:
    return server_factory()


@dataclass
class AgentThread:
    sensor_id: str
    stop: threading.Event
    thread: threading.Thread
    source: SimSource

    def halt(self) -> None:
        self.stop.set()
        self.thread.join(timeout=10)


@pytest.fixture
def agent_factory() -> Iterator[Callable[..., AgentThread]]:
    agents: list[AgentThread] = []

    def make(
        endpoint: str, sensor_id: str, position: tuple[float, float, float] = (0.0, 1.0, 3.0),
        persons: int = 1, clock_offset_ns: int = 0, pose_hint: bool = True,
        clock_drift_ppm: float = 0.0, depth: bool = True, performer: Performer | None = None,
    ) -> AgentThread:  # fmt: skip
        source = SimSource(
            performer or ProceduralPerformer(persons), look_at_pose(position, (0.0, 1.0, 0.0)),
            seed=len(agents) + 1, clock_offset_ns=clock_offset_ns, send_pose_hint=pose_hint,
            clock_drift_ppm=clock_drift_ppm,
        )  # fmt: skip
        if not depth:  # like a source whose SDK path has no depth capture
            source.request_handlers = dict  # type: ignore[method-assign]
        stop = threading.Event()
        thread = threading.Thread(
            target=run_agent, args=(sensor_id, source, endpoint), kwargs={"stop": stop},
            daemon=True,
        )  # fmt: skip
        thread.start()
        agent = AgentThread(sensor_id, stop, thread, source)
        agents.append(agent)
        return agent

    yield make
    for agent in agents:
        agent.halt()


def collect_feed(ws_url: str, frames: int, query: str = "") -> dict[int, dict[str, Any]]:
    """The JSON feed's messages by ``seq`` (``query``: e.g. ``"?rotations=1"``) until ``frames``
    of them carry persons: what an app on the WebSocket feed saw, to compare an output with."""
    feed: dict[int, dict[str, Any]] = {}
    with connect(f"{ws_url}/ws/skeletons{query}", open_timeout=10) as ws:
        ws.recv(timeout=10)  # the skeleton definition
        while sum(bool(f["persons"]) for f in feed.values()) < frames:
            message = json.loads(ws.recv(timeout=10))
            feed[message["seq"]] = message
    return feed
