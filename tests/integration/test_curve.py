"""CurveZMQ: only allowlisted agents connect, and each key speaks for one sensor id only."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
import zmq.auth

from agent.link import CurveKeys
from agent.runner import run_agent
from agent.sim.performer import ProceduralPerformer
from agent.sources.sim import SimSource
from protocol.transform import look_at_pose
from server.auth import create_agent_keys, create_server_keys, key_paths
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
