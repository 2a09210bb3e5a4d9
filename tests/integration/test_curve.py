"""CurveZMQ: only allowlisted agents connect, and each key speaks for one sensor id only."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
import zmq.auth

from skelfuse.agent.link import CurveKeys
from skelfuse.agent.runner import run_agent
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sources.sim import SimSource
from skelfuse.protocol.transform import look_at_pose
from skelfuse.server.auth import create_agent_keys, create_server_keys, key_paths
from tests.integration.conftest import LiveServer
from tests.support import wait_until

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def secured(tmp_path: Path, server_factory: Callable[..., LiveServer]) -> LiveServer:
    data = tmp_path / "data"  # the folder server_factory gives the server
    create_server_keys(data)
    create_agent_keys(data, "cam-a")
    create_agent_keys(data, "cam-b")
    return server_factory(curve=True)


@pytest.fixture
def agents() -> Iterator[Callable[[str, str, CurveKeys | None], None]]:
    stops: list[tuple[threading.Event, threading.Thread]] = []

    def start(endpoint: str, sensor_id: str, keys: CurveKeys | None) -> None:
        source = SimSource(ProceduralPerformer(1), look_at_pose((0, 1, 3), (0, 1, 0)), seed=3)
        stop = threading.Event()
        thread = threading.Thread(
            target=run_agent,
            args=(sensor_id, source, endpoint),
            kwargs={"stop": stop, "curve": keys},
            daemon=True,
        )
        thread.start()
        stops.append((stop, thread))

    yield start
    for stop, thread in stops:
        stop.set()
        thread.join(timeout=10)


def sensor_ids(live: LiveServer) -> set[str]:
    rows = httpx.get(live.http_url + "/api/sensors").json()["sensors"]
    return {r["id"] for r in rows if r["connected"]}


def test_only_allowlisted_keys_connect_each_as_its_own_sensor(
    secured: LiveServer,
    agents: Callable[[str, str, CurveKeys | None], None],
    tmp_path: Path,
) -> None:
    paths = key_paths(tmp_path / "data")

    def keys(name: str) -> CurveKeys:
        return CurveKeys(paths.agent_secret(name), paths.server_public)

    agents(secured.zmq_url, "cam-a", keys("cam-a"))  # the right key
    agents(secured.zmq_url, "intruder", None)  # no key at all
    stranger_dir = tmp_path / "stranger"
    stranger_dir.mkdir()
    _, stranger_secret = zmq.auth.create_certificates(str(stranger_dir), "stranger")
    agents(secured.zmq_url, "stranger", CurveKeys(Path(stranger_secret), paths.server_public))
    agents(secured.zmq_url, "cam-c", keys("cam-b"))  # a real key, claiming another id
    assert wait_until(lambda: sensor_ids(secured) == {"cam-a"}, timeout_s=10)
    assert wait_until(
        lambda: (
            httpx.get(secured.http_url + "/api/sensors")
            .json()["rejected_unregistered"]
            .get("key_mismatch", 0)
            > 0
        ),
        timeout_s=10,
    ), "cam-b's key must not register as cam-c"
    # Give the refused agents time to have retried; still only cam-a.
    assert not wait_until(lambda: sensor_ids(secured) != {"cam-a"}, timeout_s=3)
    assert wait_until(
        lambda: httpx.get(secured.http_url + "/api/persons").json()["persons"], timeout_s=10
    )


def test_a_restarted_agent_is_fused_again_within_2_s(
    secured: LiveServer,
    agents: Callable[[str, str, CurveKeys | None], None],
    tmp_path: Path,
) -> None:
    """An agent that crashed (no bye) and restarts with its key takes its sensor over at once."""
    import time

    import numpy as np

    from skelfuse.protocol.skeleton import JOINT_COUNT
    from skelfuse.protocol.wire import Body, Frame, Hello, encode

    paths = key_paths(tmp_path / "data")
    keys = CurveKeys(paths.agent_secret("cam-a"), paths.server_public)
    crashed = zmq.Context.instance().socket(zmq.DEALER)
    crashed.linger = 0
    keys.apply(crashed)
    crashed.connect(secured.zmq_url)
    crashed.send(encode(Hello("cam-a", "sim", "test", 30.0, time.time_ns())))
    assert crashed.poll(5000)
    crashed.recv()
    joints = np.zeros((JOINT_COUNT, 3), np.float32) + [0, 0, 2]
    crashed.send(encode(Frame(1, time.time_ns(), (Body(1, joints, np.full(25, 2, np.uint8)),))))
    assert wait_until(lambda: sensor_ids(secured) == {"cam-a"}, timeout_s=5)
    crashed.close(linger=0)  # gone without a bye, still "connected" for up to 3 s

    restarted = time.monotonic()
    agents(secured.zmq_url, "cam-a", keys)

    def fused_from_the_new_agent() -> bool:
        rows = httpx.get(secured.http_url + "/api/sensors").json()["sensors"]
        row = next(r for r in rows if r["id"] == "cam-a")
        persons = httpx.get(secured.http_url + "/api/persons").json()["persons"]
        return row["type"] == "sim" and row["frames_received"] > 1 and bool(persons)

    assert wait_until(fused_from_the_new_agent, timeout_s=10)
    assert time.monotonic() - restarted < 2.0


def test_a_second_agent_with_a_live_sensors_key_is_refused_every_time(
    secured: LiveServer, tmp_path: Path
) -> None:
    """Two real agents hold cam-a's key (a copied key file, an agent started twice): the second
    is refused while the first is live, never welcomed, so none of its frames is fused."""
    import time

    from skelfuse.agent.link import AgentLink
    from skelfuse.protocol.transform import look_at_pose as pose

    paths = key_paths(tmp_path / "data")
    keys = CurveKeys(paths.agent_secret("cam-a"), paths.server_public)
    links: dict[str, AgentLink] = {}
    stops: list[tuple[threading.Event, threading.Thread]] = []

    def start(name: str, position: tuple[float, float, float]) -> None:
        source = SimSource(ProceduralPerformer(1), pose(position, (0, 1, 0)), seed=len(links))
        stop = threading.Event()

        def run() -> None:
            links[name] = run_agent("cam-a", source, secured.zmq_url, stop=stop, curve=keys)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        stops.append((stop, thread))

    def row() -> dict[str, object]:
        rows = httpx.get(secured.http_url + "/api/sensors").json()
        sensor: dict[str, object] = next(r for r in rows["sensors"] if r["id"] == "cam-a")
        sensor["refused"] = rows["rejected_unregistered"].get("sensor_id_in_use", 0)
        return sensor

    try:
        start("first", (0.0, 1.0, 3.0))
        assert wait_until(lambda: row()["connected"] and row()["frames_received"] > 30, 15)
        first_pose = row()["calibration"]["T_world_from_sensor"]  # type: ignore[index]
        start("second", (2.6, 1.0, -1.5))  # its pose hint would show if it ever took over
        watched_until = time.monotonic() + 4.0
        while time.monotonic() < watched_until:
            now = row()
            assert now["connected"]
            assert now["calibration"]["T_world_from_sensor"] == first_pose  # type: ignore[index]
            time.sleep(0.1)
        assert row()["refused"] >= 2  # type: ignore[operator]
    finally:
        for stop, thread in stops:
            stop.set()
            thread.join(timeout=10)
    second = links["second"]
    assert second.stats.registrations == 0, "the second agent was welcomed"
    assert second.stats.frames_sent == 0
    assert second.stats.server_errors.get("sensor_id_in_use", 0) >= 2
    assert links["first"].stats.registrations == 1


def test_an_agent_without_a_key_is_told_why_and_the_server_counts_it(
    secured: LiveServer, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Issue 12 #8: the handshake still refuses them, but neither side is silent any more."""
    import logging
    import time

    from skelfuse.agent.link import AgentLink
    from skelfuse.protocol.wire import Hello

    caplog.set_level(logging.WARNING)
    stranger_dir = tmp_path / "stranger"
    stranger_dir.mkdir()
    _, stranger_secret = zmq.auth.create_certificates(str(stranger_dir), "stranger")
    server_public = key_paths(tmp_path / "data").server_public

    def hello() -> Hello:
        return Hello("cam-a", "sim", "test", 30.0, time.time_ns())

    keyless = AgentLink(secured.zmq_url, hello)
    stranger = AgentLink(
        secured.zmq_url, hello, curve=CurveKeys(Path(stranger_secret), server_public)
    )

    def refused() -> dict[str, int]:
        rows = httpx.get(secured.http_url + "/api/sensors").json()
        counts: dict[str, int] = rows["rejected_unregistered"]
        return counts

    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not (
            keyless.handshake.failures and stranger.handshake.failures
        ):
            keyless.poll(0.05)
            stranger.poll(0.05)
        assert keyless.handshake.failures.get("no_key", 0) >= 1
        assert stranger.handshake.failures.get("key_refused", 0) >= 1
        assert not keyless.registered and not stranger.registered
        agent_lines = [
            r.getMessage() for r in caplog.records if r.name.startswith("skelfuse.agent")
        ]
        assert any("requires CurveZMQ" in line and "--key" in line for line in agent_lines)
        assert any("refused this agent's CurveZMQ key" in line for line in agent_lines)
        # The keyless agent hangs up first (it sees the mechanism mismatch), so the server
        # mostly sees a handshake without detail; a key it does not know, it names.
        assert wait_until(
            lambda: (
                refused().get("handshake_no_key", 0) + refused().get("handshake_failed", 0) >= 1
                and refused().get("handshake_key_refused", 0) >= 1
            ),
            timeout_s=5,
        ), refused()
        server_lines = [
            r.getMessage() for r in caplog.records if r.name.startswith("skelfuse.server")
        ]
        assert any("without a CurveZMQ key" in line for line in server_lines)
        assert any("not allowlisted" in line for line in server_lines)
    finally:
        keyless.close()
        stranger.close()
