"""A burst of 12,000 malformed messages from one peer (issue 12 #10), over real ZeroMQ sockets into
the real ingest loop and hub, while a real agent link streams well-formed frames:

- the event loop keeps turning: the ingest loop hands it back between short slices, so other
  tasks (the fusion loop, the web server) run while the burst is drained, instead of after it;
- the flooder's rejections are bounded: past its budget its messages are dropped unread;
- the well-formed agent loses nothing.

Counting messages between turns rather than timing them keeps the test meaningful on a loaded
machine; ``bench/live/malformed_burst.py`` measures the feed's longest pause with real processes.
"""

from __future__ import annotations

import asyncio
import itertools
import threading
import time

import pytest
import zmq
import zmq.asyncio

from bench.live.malformed_burst import malformed
from skelfuse.agent.link import AgentLink
from skelfuse.protocol.wire import Frame, Hello
from skelfuse.server.hub import FusionHub
from skelfuse.server.ingest import ingest_loop, liveness_loop, open_router
from skelfuse.server.rejection_budget import REJECTIONS_PER_WINDOW
from skelfuse.server.settings import Settings
from tests.support import free_port

pytestmark = pytest.mark.timeout(60)

BURST = 12_000


def refused(hub: FusionHub) -> int:
    return sum(hub.rejected_unregistered.values())


async def test_a_malformed_burst_neither_stalls_the_loop_nor_costs_a_good_agent_a_frame() -> None:
    context = zmq.asyncio.Context()
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    router = open_router(context, endpoint)
    hub = FusionHub(Settings())
    tasks = [
        asyncio.create_task(ingest_loop(router, hub, False)),
        asyncio.create_task(liveness_loop(router, hub, 1.0)),
    ]
    stop = threading.Event()
    sent: list[int] = []

    def good_agent() -> None:
        link = AgentLink(endpoint, lambda: Hello("cam", "sim", "t", 30.0, time.time_ns()))
        seq = 0
        try:
            while not stop.is_set():
                link.poll(1 / 30)
                if link.registered:
                    seq += 1
                    if link.send_frame(Frame(seq, time.time_ns(), ())):
                        sent.append(seq)
        finally:
            link.close()

    agent = threading.Thread(target=good_agent, daemon=True)
    agent.start()
    flooder = zmq.Context.instance().socket(zmq.DEALER)
    flooder.sndhwm = BURST + 10
    flooder.linger = 0
    flooder.connect(endpoint)
    try:
        for _ in range(200):
            if len(sent) > 10:
                break
            await asyncio.sleep(0.05)
        assert len(sent) > 10, "the good agent did not start streaming"
        # Queue the whole burst before the ingest loop can see it: a burst that is already
        # there when the loop wakes is what used to hold the loop for its whole length.
        payloads = [malformed(i) for i in range(BURST)]
        for payload in payloads:
            flooder.send(payload)
        # A ticker task notes how many messages were refused at each of its turns.
        seen: list[int] = [refused(hub)]
        deadline = time.monotonic() + 30
        while refused(hub) < BURST and time.monotonic() < deadline:
            await asyncio.sleep(0)
            seen.append(refused(hub))
        assert refused(hub) >= BURST, dict(hub.rejected_unregistered)
        most_between_turns = max(b - a for a, b in itertools.pairwise(seen))
        # One ingest slice is 5 ms; thousands of messages in one turn means the loop stalled.
        assert most_between_turns <= 2_000, most_between_turns
        assert len(seen) > 5, "the burst was drained in one go"
        # Bounded work: past its budget the flooder's messages were dropped unread.
        unread = hub.rejected_unregistered["rate_limited"]
        assert unread >= BURST - 3 * REJECTIONS_PER_WINDOW, dict(hub.rejected_unregistered)
        stop.set()
        await asyncio.to_thread(agent.join, 10)
        for _ in range(100):  # the good agent's last frames arrive
            if "cam" in hub.sensors and hub.sensors["cam"].frames_received >= len(sent):
                break
            await asyncio.sleep(0.02)
    finally:
        stop.set()
        await asyncio.to_thread(agent.join, 10)
        flooder.close(linger=0)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        router.close(linger=0)
        context.term()
    cam = hub.sensors["cam"]
    assert not cam.frames_rejected, dict(cam.frames_rejected)
    assert cam.sequence_gaps == 0
    assert cam.frames_received == len(sent)
