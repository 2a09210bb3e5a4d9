"""A real server's outputs (real uvicorn, ZeroMQ ingest, two simulated agents): an OSC receiver
(python-osc) gets every fused frame, none lost, every datagram within 1,472 bytes, with the
values a WebSocket client of the same server gets (as float32); a VMC receiver gets the avatar;
``/metrics`` counts what each output sent and dropped."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import numpy as np

from skelfuse.protocol.skeleton import JOINT_NAMES
from skelfuse.server import osc_encoding as osc
from skelfuse.server.settings import OutputSpec
from tests.integration.conftest import AgentThread, LiveServer, collect_feed
from tests.unit.test_outputs_osc import Receiver

FRAMES = 30


def test_osc_and_vmc_get_every_fused_frame_with_the_feed_values(
    server_factory: Callable[..., LiveServer], agent_factory: Callable[..., AgentThread]
) -> None:
    osc_receiver, vmc_receiver = Receiver(), Receiver()
    live = server_factory(
        outputs=(
            OutputSpec("osc", "127.0.0.1", osc_receiver.port, rotations=True),
            OutputSpec("vmc", "127.0.0.1", vmc_receiver.port),
        )
    )
    agent_factory(live.zmq_url, "cam-a", (0.0, 1.0, 3.0), depth=False)
    agent_factory(live.zmq_url, "cam-b", (2.6, 1.0, -1.5), depth=False)
    feed = collect_feed(live.ws_url, FRAMES, "?rotations=1")
    metrics = httpx.get(live.http_url + "/metrics/").text
    live.stop()
    osc_receiver.wait_for(10**6, timeout_s=1.0)
    vmc_receiver.wait_for(10**6, timeout_s=1.0)

    assert all(len(d) <= osc.MAX_DATAGRAM for d in osc_receiver.datagrams + vmc_receiver.datagrams)
    received: dict[int, dict[str, list[float]]] = {}
    seq = -1
    for message in osc_receiver.messages():
        if message.address == "/skelfuse/frame":
            seq = message.params[0]
            received[seq] = {}
        elif message.address.startswith("/skelfuse/person/"):
            received[seq][message.address] = list(message.params)
    seqs = sorted(received)
    assert seqs == list(range(seqs[0], seqs[-1] + 1)), "an OSC frame was lost"
    compared = 0
    for seq, message in feed.items():
        for person in message["persons"]:  # type: ignore[attr-defined]
            base = f"/skelfuse/person/{person['id']}"
            for name, row, confidence, rotation in zip(
                JOINT_NAMES, person["joints"], person["confidence"], person["rotations"],
                strict=True,
            ):  # fmt: skip
                if row is None:
                    assert f"{base}/{name}" not in received[seq]
                    continue
                got = received[seq][f"{base}/{name}"]
                assert np.array_equal(np.float32(got), np.float32([*row, confidence]))
                assert np.array_equal(np.float32(received[seq][f"{base}/{name}/rot"]),
                                      np.float32(rotation))  # fmt: skip
                compared += 1
    assert compared >= FRAMES * 20
    vmc = vmc_receiver.messages()
    assert sum(m.address == "/VMC/Ext/Bone/Pos" and m.params[0] == "Hips" for m in vmc) >= FRAMES
    for name in (f"osc:127.0.0.1:{osc_receiver.port}", f"vmc:127.0.0.1:{vmc_receiver.port}"):
        assert f'skelfuse_output_dropped_total{{output="{name}"}} 0.0' in metrics
        assert f'skelfuse_output_sent_total{{output="{name}"}}' in metrics
