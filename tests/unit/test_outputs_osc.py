"""OSC and VMC outputs on real loopback sockets, read back with python-osc (an independent
decoder): every datagram fits 1,472 bytes, none lost, values equal to the WebSocket feed's as
float32; the VMC avatar rests in identity and rebuilds the fused joints; a stalled output drops
and counts without slowing fusion or the other outputs."""

from __future__ import annotations

import functools
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage

from skelfuse.fusion.engine import FusedFrame
from skelfuse.geometry.quaternion import quaternion_multiply, quaternion_rotate
from skelfuse.protocol.feed import persons_json
from skelfuse.protocol.skeleton import JOINT_NAMES
from skelfuse.recording.replay import replay
from skelfuse.server import osc_encoding as osc
from skelfuse.server.output_osc import OscSink, VmcSink, persons_orientations
from skelfuse.server.outputs import Fanout, QueuedOutput
from skelfuse.server.vmc import _AT, HUMANOID, humanoid_pose, to_unity_points

TAKE = Path(__file__).resolve().parents[1] / "data" / "golden" / "take.sfrec"
FRAMES = 30


@functools.cache
def fused_frames(count: int = FRAMES) -> list[FusedFrame]:
    """The first ``count`` frames with people of the golden take, fused (replayed once)."""
    frames = [f for f in replay(TAKE) if f.persons]
    assert len(frames) >= count
    return frames[:count]


class Receiver:
    """A UDP socket on loopback that collects datagrams in a thread, as python-osc reads them."""

    def __init__(self) -> None:
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(0.1)
        self.port: int = self.socket.getsockname()[1]
        self.datagrams: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.datagrams.append(self.socket.recv(65536))
            except TimeoutError:
                continue

    def wait_for(self, count: int, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while len(self.datagrams) < count and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.1)  # any extra datagram would arrive now
        self._stop.set()
        self._thread.join()
        self.socket.close()

    def messages(self) -> list[OscMessage]:
        out: list[OscMessage] = []
        for datagram in self.datagrams:
            assert OscBundle.dgram_is_bundle(datagram)
            out.extend(m for m in OscBundle(datagram) if isinstance(m, OscMessage))
        return out


def test_encoder_matches_python_osc_on_every_type_and_padding() -> None:
    for address in ("/a", "/ab", "/abc", "/abcd"):  # every padding of the address
        data = osc.message(address, "idifs", [3, 1763712345.1234, -5, 0.5, "abc"])
        assert len(data) % 4 == 0
        decoded = OscMessage(data)
        assert decoded.address == address
        assert decoded.params == [3, 1763712345.1234, -5, 0.5, "abc"]  # float64 keeps seconds
    with pytest.raises(osc.OscError):
        osc.message("/a", "ff", [1.0])
    with pytest.raises(osc.OscError):
        osc.pack_bundles([b"x" * 1460])


def test_pack_bundles_keeps_order_and_fits_each_datagram() -> None:
    elements = [osc.message(f"/j/{k}", "ffff", [k, 0, 0, 1]) for k in range(200)]
    datagrams = osc.pack_bundles(elements)
    assert len(datagrams) > 1
    assert all(len(d) <= osc.MAX_DATAGRAM for d in datagrams)
    addresses = [m.address for d in datagrams for m in OscBundle(d)]
    assert addresses == [f"/j/{k}" for k in range(200)]


def test_osc_output_sends_30_fused_frames_whole_and_equal_to_the_feed() -> None:
    frames = fused_frames()
    receiver = Receiver()
    output = QueuedOutput("osc", OscSink("127.0.0.1", receiver.port, rotations=True), 64)
    output.start()
    for frame in frames:
        output.publish(frame, frame.t_s, 0.0)
    output.close(timeout_s=30)
    assert (output.sent, output.dropped, output.messages_dropped) == (FRAMES, 0, 0)
    expected: dict[str, list[float]] = {}
    for frame in frames:
        people = persons_json(frame.persons, orientations=persons_orientations(frame.persons))
        for person in people:
            joints, confidence = person["joints"], person["confidence"]
            for j, name in enumerate(JOINT_NAMES):
                row = joints[j]  # type: ignore[index]
                if row is not None:
                    key = f"{frame.seq}/skelfuse/person/{person['id']}/{name}"
                    expected[key] = [*row, confidence[j]]  # type: ignore[index]
                    expected[key + "/rot"] = person["rotations"][j]  # type: ignore[index]
    receiver.wait_for(10**6, timeout_s=2.0)
    assert all(len(d) <= osc.MAX_DATAGRAM for d in receiver.datagrams)
    got: dict[str, list[float]] = {}
    seqs: list[int] = []
    seq = -1
    for message in receiver.messages():
        if message.address == "/skelfuse/frame":
            seq, t_s, whole, micros, _ = message.params
            assert t_s == frames[len(seqs)].t_s  # float64: to the bit
            assert abs(whole + micros * 1e-6 - t_s) <= 1e-6
            seqs.append(seq)
        elif message.address.startswith("/skelfuse/person/"):
            got[f"{seq}{message.address}"] = list(message.params)
    assert seqs == [f.seq for f in frames]
    assert got.keys() == expected.keys()
    for key, values in expected.items():
        assert np.array_equal(np.float32(values), np.float32(got[key])), key


def test_vmc_rest_pose_is_identity_and_forward_kinematics_rebuilds_the_joints() -> None:
    frame = fused_frames()[10]
    person = frame.persons[0]
    world = persons_orientations([person]).world[0]  # type: ignore[union-attr]
    positions, local, known = humanoid_pose(person.joints, world)
    # Forward kinematics down the humanoid chain, in Unity's axes, gives the fused joints back.
    names = [name for name, _, _ in HUMANOID]
    unity = to_unity_points(person.joints)
    bone_world: dict[str, np.ndarray] = {}
    bone_at: dict[str, np.ndarray] = {}
    for k, (name, _, parent) in enumerate(HUMANOID):
        if parent is None:
            bone_world[name], bone_at[name] = local[k], positions[k]
        else:
            bone_world[name] = quaternion_multiply(bone_world[parent], local[k])
            bone_at[name] = bone_at[parent] + quaternion_rotate(bone_world[parent], positions[k])
    for k, name in enumerate(names):
        if known[k]:
            assert np.allclose(bone_at[name], unity[_AT[k]], atol=1e-9), name
    # A still T-pose (every bone rotation identity) is the avatar's rest: identity locals.
    identity = np.tile([0.0, 0.0, 0.0, 1.0], (25, 1))
    _, rest, _ = humanoid_pose(person.joints, identity)
    assert np.allclose(rest, [0.0, 0.0, 0.0, 1.0])


def test_vmc_output_sends_every_bone_of_30_frames_in_datagrams_that_fit() -> None:
    frames = fused_frames()
    receiver = Receiver()
    output = QueuedOutput("vmc", VmcSink("127.0.0.1", receiver.port), 64)
    output.start()
    for frame in frames:
        output.publish(frame, frame.t_s, 0.0)
    output.close(timeout_s=30)
    assert (output.sent, output.dropped) == (FRAMES, 0)
    receiver.wait_for(10**6, timeout_s=2.0)
    assert all(len(d) <= osc.MAX_DATAGRAM for d in receiver.datagrams)
    messages = receiver.messages()
    assert sum(m.address == "/VMC/Ext/OK" for m in messages) == FRAMES
    assert sum(m.address == "/VMC/Ext/T" for m in messages) == FRAMES
    assert sum(m.address == "/VMC/Ext/Root/Pos" for m in messages) == FRAMES
    bones = [m for m in messages if m.address == "/VMC/Ext/Bone/Pos"]
    names = {name for name, _, _ in HUMANOID}
    assert {m.params[0] for m in bones} <= names
    assert all(len(m.params) == 8 for m in bones)
    hips = [m.params for m in bones if m.params[0] == "Hips"]
    assert len(hips) == FRAMES
    for frame, params in zip(frames, hips, strict=True):
        person = min(frame.persons, key=lambda p: p.person_id)
        pelvis = np.round(person.joints[0], 4) * [-1.0, 1.0, 1.0]  # the feed's, in Unity's axes
        assert np.array_equal(np.float32(params[1:4]), np.float32(pelvis))


class _StalledSink:
    """A sink whose receiver never takes anything: each send blocks until released."""

    def __init__(self) -> None:
        self.release = threading.Event()

    def send(self, frame: FusedFrame) -> int:
        self.release.wait(10.0)
        return 0

    def close(self) -> None:
        self.release.set()


def test_a_stalled_output_drops_and_counts_while_fusion_and_the_others_go_on() -> None:
    frames = fused_frames()
    receiver = Receiver()
    healthy = QueuedOutput("osc", OscSink("127.0.0.1", receiver.port), capacity=64)
    stalled = QueuedOutput("stalled", _StalledSink(), capacity=4)
    fanout = Fanout([stalled, healthy])
    for output in (healthy, stalled):
        output.start()
    slowest = 0.0
    for frame in frames:
        started = time.perf_counter()
        fanout.publish(frame, frame.t_s, 0.0)
        slowest = max(slowest, time.perf_counter() - started)
    assert slowest < 0.05  # never waits for the stalled sink (a send blocks it for 10 s)
    # At most one frame in the stalled sink's send and four queued: the rest dropped, counted.
    assert stalled.dropped >= FRAMES - 1 - 4
    assert stalled.sent == 0
    healthy.close(timeout_s=30)
    stalled.close()
    assert (healthy.sent, healthy.dropped) == (FRAMES, 0)
    receiver.wait_for(10**6, timeout_s=2.0)
    frames_received = [m for m in receiver.messages() if m.address == "/skelfuse/frame"]
    assert len(frames_received) == FRAMES


def test_an_output_whose_receiver_is_gone_neither_raises_nor_stops() -> None:
    gone = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gone.bind(("127.0.0.1", 0))
    port = gone.getsockname()[1]
    gone.close()  # nobody listens there now: loopback answers each datagram "port unreachable"
    output = QueuedOutput("osc", OscSink("127.0.0.1", port), capacity=64)
    output.start()
    for frame in fused_frames():
        output.publish(frame, frame.t_s, 0.0)
    output.close(timeout_s=30)
    # UDP has no delivery report (an unconnected socket ignores "port unreachable"): every
    # frame counts as sent, and no send failed.
    assert (output.sent, output.dropped, output.messages_dropped) == (FRAMES, 0, 0)
