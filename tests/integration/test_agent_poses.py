"""A real agent as ``skelfuse agent --source sim --pose-source file:PATH --pose-space ...``
builds it (the command line's own functions) streams frames with their poses: a ROUTER socket
plays a server that announces ``moving_sensors``; frames whose capture instant falls in a gap
of the pose file are not sent, and their ``seq`` numbers are missing. Then against a real
server, which places the frames by their poses."""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import zmq

from skelfuse.agent.link import MOVING_SENSORS
from skelfuse.agent.poses.posed import PosedSource
from skelfuse.agent.runner import run_agent
from skelfuse.cli import build_parser
from skelfuse.cli.agent import source_from_args
from skelfuse.cli.agent_poses import posed_from_args
from skelfuse.protocol.sensor_pose import pose_from_matrix
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import pose_from_position_yaw_pitch
from skelfuse.protocol.wire import Frame, Heartbeat, Hello, Welcome, decode, encode
from tests.integration.conftest import LiveServer, collect_feed
from tests.support import free_port, wait_until

STEP_NS = 10_000_000  # the pose file's 100 Hz
GAP = (50, 100)  # samples 0.5 s .. 1.0 s after the start are missing: a lost tracker
# The track starts this long after the agent (which registers within ~1 s: its first hello
# goes before the connection is up and is dropped); frames before it have no pose either.
LEAD_NS = 2_000_000_000


def walking_track(path: Path, t0_ns: int, samples: int) -> None:
    """A head walking along +X at 1 m/s on the agent's clock (``t_ns`` rows), with a gap."""
    rows = [
        f"{t0_ns + k * STEP_NS},{k * STEP_NS / 1e9:.6f},1.6,0,0,0,0,1"
        for k in range(samples)
        if not GAP[0] < k < GAP[1]
    ]
    path.write_text("t_ns,px,py,pz,qx,qy,qz,qw\n" + "\n".join(rows) + "\n")


def serve(socket: zmq.Socket[Any], seconds: float) -> tuple[Hello, list[Frame]]:
    """Answer the agent's hello with a welcome listing moving_sensors, its heartbeats with
    one (it echoes that one back); collect frames for ``seconds``."""
    hello: Hello | None = None
    frames: list[Frame] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if not socket.poll(50):
            continue
        routing_id, payload = socket.recv_multipart()
        message = decode(payload)
        if isinstance(message, Hello):
            hello = message
            welcome = Welcome("test", 1.0, time.time_ns(), (MOVING_SENSORS,))
            socket.send_multipart([routing_id, encode(welcome)])
        elif isinstance(message, Heartbeat) and message.echo_ns is None:
            socket.send_multipart([routing_id, encode(Heartbeat(time.time_ns()))])
        elif isinstance(message, Frame):
            frames.append(message)
    assert hello is not None, "the agent never said hello"
    return hello, frames


@pytest.mark.timeout(60)
def test_the_agent_streams_each_frame_with_its_pose_and_skips_unposed_ones(
    tmp_path: Path,
) -> None:
    port = free_port()
    context: zmq.Context[Any] = zmq.Context()
    router = context.socket(zmq.ROUTER)
    router.linger = 0
    router.bind(f"tcp://127.0.0.1:{port}")
    t0_ns = time.time_ns() + LEAD_NS
    track = tmp_path / "head.csv"
    walking_track(track, t0_ns, samples=200)
    args = build_parser().parse_args(
        ["agent", "--id", "head-a", "--server", f"tcp://127.0.0.1:{port}", "--persons", "1",
         "--pose-source", f"file:{track}", "--pose-space", "room-a"]
    )  # fmt: skip
    source = posed_from_args(args, source_from_args(args))
    assert isinstance(source, PosedSource)
    stop = threading.Event()
    agent = threading.Thread(
        target=run_agent, args=("head-a", source, args.server), kwargs={"stop": stop}, daemon=True
    )
    agent.start()
    try:
        hello, frames = serve(router, seconds=max(0.0, (t0_ns / 1e9 + 1.6) - time.time()))
    finally:
        stop.set()
        agent.join(timeout=10)
        router.close(linger=0)
        context.term()
    assert hello.moving and hello.pose_space == "room-a" and hello.pose_hint is None
    assert len(frames) > 20, f"only {len(frames)} frames"
    for frame in frames:
        assert frame.pose is not None
        t_s = (frame.t_capture_ns - t0_ns) / 1e9
        held = min(max(t_s, 0.0), 1.99)  # the end poses are held for 50 ms
        assert frame.pose.position_m == pytest.approx((held, 1.6, 0.0), abs=1e-6)
        # None inside the gap (beyond the track's 0.25 s gap rule).
        assert not GAP[0] * 0.01 < t_s < GAP[1] * 0.01
    # The frames of the gap were captured (their seq counted) but not sent.
    before = [f for f in frames if f.t_capture_ns < t0_ns + GAP[0] * STEP_NS]
    after = [f for f in frames if f.t_capture_ns > t0_ns + GAP[1] * STEP_NS]
    assert before and after, f"{len(before)} frames before the gap, {len(after)} after"
    seqs = [f.seq for f in frames]
    assert seqs == sorted(seqs)
    assert max(b - a for a, b in itertools.pairwise(seqs)) >= 10  # ~0.5 s at 30 fps
    assert source.unposed["in a gap of the pose file"] >= 10
    assert source.unposed["before the pose file's first sample"] > 0


def test_a_real_server_places_the_cli_agents_frames_by_their_poses(
    live_server: LiveServer, tmp_path: Path
) -> None:
    # The sim stands at 0,1,3 looking back at the origin; the pose file says exactly that
    # sensor pose, held (a moving sensor that happens to stand still). With no fixed sensor the
    # lone space is the world, so the person (walking a 0.9 m circle about the origin) is fused
    # about the origin only if every frame was placed by its pose: without it they would be
    # fused in the sensor's frame, about 3 m in front of the origin.
    sensor = pose_from_matrix(pose_from_position_yaw_pitch((0.0, 1.0, 3.0), 180.0))
    row = ",".join(str(v) for v in (*sensor.position_m, *sensor.rotation_xyzw))
    track = tmp_path / "still.csv"
    track.write_text(f"t_s,px,py,pz,qx,qy,qz,qw\n0,{row}\n0.1,{row}\n")
    args = build_parser().parse_args(
        ["agent", "--id", "head-a", "--server", live_server.zmq_url, "--persons", "1",
         "--pose=0,1.0,3.0,180", "--pose-source", f"file:{track}", "--pose-space", "room-a",
         "--pose-loop"]
    )  # fmt: skip
    source = posed_from_args(args, source_from_args(args))
    stop = threading.Event()
    agent = threading.Thread(
        target=run_agent, args=("head-a", source, args.server), kwargs={"stop": stop}, daemon=True
    )
    agent.start()
    try:

        def sensor_row() -> dict[str, Any]:
            rows = httpx.get(live_server.http_url + "/api/sensors", timeout=5).json()["sensors"]
            return next((r for r in rows if r["id"] == "head-a"), {})

        assert wait_until(lambda: sensor_row().get("frames_received", 0) > 10, 30), sensor_row()
        assert sensor_row()["calibration"]["state"] == "floor"
        feed = collect_feed(live_server.ws_url, 10)
        hips = [
            np.array(person["joints"])[JointId.SPINE_BASE, :3]
            for message in feed.values()
            for person in message["persons"]
        ]
        assert hips
        for hip in hips:
            assert float(np.hypot(hip[0], hip[2])) < 1.4, hip  # on its circle, not 3 m away
        assert set(sensor_row()["frames_rejected"]) <= {"stale"}  # none refused for its pose
    finally:
        stop.set()
        agent.join(timeout=10)


def test_mutual_capture_from_the_command_line_on_a_real_server(live_server: LiveServer) -> None:
    # Three people on a 1.5 m ring, each wearing a head-mounted sensor looking at the others:
    # three agents as `skelfuse agent --source sim --scenario mutual --wearer N` builds them.
    agents, stop = [], threading.Event()
    for wearer in range(3):
        args = build_parser().parse_args(
            ["agent", "--id", f"head-{wearer}", "--server", live_server.zmq_url, "--persons",
             "3", "--scenario", "mutual", "--wearer", str(wearer), "--walk-m", "0"]
        )  # fmt: skip
        source = posed_from_args(args, source_from_args(args))
        thread = threading.Thread(
            target=run_agent, args=(args.id, source, args.server), kwargs={"stop": stop},
            daemon=True,
        )  # fmt: skip
        thread.start()
        agents.append(thread)
    try:

        def rows() -> list[dict[str, Any]]:
            got: list[dict[str, Any]] = httpx.get(
                live_server.http_url + "/api/sensors", timeout=5
            ).json()["sensors"]
            return got

        def streaming() -> bool:
            got = rows()
            return len(got) == 3 and all(r["frames_received"] > 10 for r in got)

        assert wait_until(streaming, 30), rows()
        # None refused (no_pose, a bad pose...); "stale" would only be a starved test machine.
        assert all(set(r["frames_rejected"]) <= {"stale"} for r in rows()), rows()
        feed = collect_feed(live_server.ws_url, 10)
        last = list(feed.values())[-1]
        hips = [np.array(p["joints"])[JointId.SPINE_BASE, :3] for p in last["persons"]]
        # Person i stands at angle 2πi/3 on the ring (0 on the +Z side): each one fused there.
        for i in range(3):
            angle = 2 * np.pi * i / 3
            truth = np.array([1.5 * np.sin(angle), 1.5 * np.cos(angle)])
            nearest = min(float(np.linalg.norm(h[[0, 2]] - truth)) for h in hips)
            assert nearest < 0.3, (i, hips)
    finally:
        stop.set()
        for thread in agents:
            thread.join(timeout=10)
