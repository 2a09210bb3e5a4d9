"""skelfuse.client against a real uvicorn server fed by simulated agents over ZeroMQ: rotations
that forward kinematics turns back into the fused joints, the token, reconnection (the
examples of docs/api.md: tests/integration/test_api_examples.py)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import pytest

from skelfuse.client import (
    Backoff,
    FeedClient,
    FeedRefused,
    FeedUnavailable,
    Frame,
    SyncFeedClient,
)
from skelfuse.client.frames import person_from
from tests.integration.conftest import AgentThread, LiveServer
from tests.integration.test_live_pipeline import start_two
from tests.unit.test_joint_orientations import chain_known, forward_kinematics

pytestmark = pytest.mark.timeout(120)
API_MD = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def fk_error_m(person_joints: np.ndarray, rotations: object) -> float:
    """Largest distance (m) between a person's joints (those whose chain to the root is known)
    and FK from its local rotations."""
    local = np.asarray(rotations.local)  # type: ignore[attr-defined]
    local = local / np.linalg.norm(local, axis=1, keepdims=True)  # sent to 1e-5
    known = chain_known(person_joints)
    root = person_joints[0] if known[0] else np.zeros(3)
    positions = forward_kinematics(root, local, rotations.rest_offsets)  # type: ignore[attr-defined]
    return float(np.abs(positions - person_joints)[known].max())


async def test_rotations_in_the_live_feed_give_the_fused_joints_back(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    start_two(live_server, agent_factory, persons=2)
    async with (
        FeedClient(live_server.http_url, rotations=True) as feed,
        FeedClient(live_server.http_url, format="msgpack", raw=True) as plain,
    ):
        assert feed.skeleton is not None and feed.skeleton.joints[3] == "Head"
        frames = [await feed.next_frame() for _ in range(45)]
        other = await plain.next_frame()
    persons = [p for f in frames for p in f.persons]
    assert len(persons) > 45 and all(p.rotations is not None for p in persons)
    worst = max(fk_error_m(p.joints, p.rotations) for p in persons)
    assert worst < 0.005, f"{worst * 1000:.2f} mm"
    assert frames[-1].received is not None and frames[-1].received >= frames[-1].t
    assert other.raw and all(p.rotations is None for p in other.persons)
    url = live_server.http_url + "/api/persons?rotations=1"
    rest = (await asyncio.to_thread(httpx.get, url, timeout=5)).json()
    assert rest["persons"] and all("local_rotations" in p for p in rest["persons"])
    person = person_from(rest["persons"][0])
    assert fk_error_m(person.joints, person.rotations) < 0.005


def test_the_token_is_taken_and_a_refusal_is_not_retried(
    server_factory: Callable[..., LiveServer], agent_factory: Callable[..., AgentThread]
) -> None:
    live = server_factory(api_token="s3cret")
    slept: list[float] = []
    with pytest.raises(FeedRefused, match="HTTP 403") as info:
        SyncFeedClient(live.http_url, token="wrong", sleep=slept.append).connect()
    assert info.value.status == 403 and slept == [] and "s3cret" not in str(info.value)
    agent_factory(live.zmq_url, "cam-a")
    frames = []
    with SyncFeedClient(live.http_url, token="s3cret") as feed:
        for frame in feed:
            frames.append(frame)
            if len(frames) == 5:
                break
    assert [f.seq for f in frames] == sorted({f.seq for f in frames})


async def test_the_client_waits_for_the_server_and_reconnects_after_a_restart(
    server_factory: Callable[..., LiveServer], agent_factory: Callable[..., AgentThread]
) -> None:
    first = server_factory()  # to learn the fixture's ports; every server it makes takes them
    url, zmq_url = first.http_url, first.zmq_url
    first.stop()
    with pytest.raises(FeedUnavailable, match="no feed at"):
        await FeedClient(url, reconnect=False).connect()
    slept: list[float] = []
    servers: list[LiveServer] = []

    async def start_a_server_on_the_second_pause(delay: float) -> None:
        slept.append(delay)
        if len(slept) % 2 == 0:  # nothing listened for two attempts
            servers.append(await asyncio.to_thread(server_factory))

    backoff = Backoff(first_s=0.125, factor=2.0, max_s=1.0)
    async with FeedClient(url, backoff=backoff, sleep=start_a_server_on_the_second_pause) as feed:
        assert slept == [0.125, 0.25] and feed.connections == 1
        agent_factory(zmq_url, "cam-a")
        before = await asyncio.wait_for(feed.next_frame(), 20)
        await asyncio.to_thread(servers[0].stop)
        after = await asyncio.wait_for(_first_frame_of_connection(feed, 2), 30)
        assert feed.connections == 2 and slept == [0.125, 0.25, 0.125, 0.25]
    assert after.seq < before.seq or after.t > before.t  # a new server counts from 1 again


async def _first_frame_of_connection(feed: FeedClient, connection: int) -> Frame:
    """Frames read ahead of a drop (one or two) are still delivered: skip them."""
    while True:
        frame = await feed.next_frame()
        if feed.connections >= connection:
            return frame
