"""OSC and VMC outputs: fused frames as OSC bundles over UDP (docs/outputs.md).

Both send the numbers the WebSocket feed sends (``protocol/feed.py``'s rounding: positions to
0.1 mm, rotations to 1e-5), as OSC float32; every datagram is one bundle of at most
:data:`~skelfuse.server.osc_encoding.MAX_DATAGRAM` bytes. The socket is non-blocking: a datagram the
kernel cannot take at once is not sent, and counted (``Sink.send``'s return).
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.views import FusedPerson
from skelfuse.protocol.feed import persons_json
from skelfuse.protocol.skeleton import JOINT_NAMES
from skelfuse.recording.joint_orientations import Orientations, orientations
from skelfuse.server import osc_encoding as osc
from skelfuse.server.vmc import HUMANOID, humanoid_pose

OSC_PREFIX = "/skelfuse"


def persons_orientations(persons: Sequence[FusedPerson]) -> Orientations | None:
    """The persons' joint rotations, as the feed computes them (None for nobody)."""
    return orientations(np.stack([p.joints for p in persons])) if persons else None


class SharedRotations:
    """Each frame's rotations computed once for every output that sends them (OSC and VMC in
    their own threads): they cost milliseconds a frame, the rest of the encoding a fraction."""

    def __init__(self, keep: int = 4) -> None:
        self._lock = threading.Lock()
        self._recent: OrderedDict[int, tuple[FusedFrame, Orientations | None]] = OrderedDict()
        self._keep = keep

    def of(self, frame: FusedFrame) -> Orientations | None:
        """The rotations of ``frame.persons``, in their order (None for nobody)."""
        # Computed under the lock: the second output waits for the first one's result rather
        # than computing it again at the same moment.
        with self._lock:
            hit = self._recent.get(id(frame))
            if hit is not None and hit[0] is frame:
                return hit[1]
            value = persons_orientations(frame.persons)
            self._recent[id(frame)] = (frame, value)
            while len(self._recent) > self._keep:
                self._recent.popitem(last=False)
            return value


ROTATIONS = SharedRotations()


class UdpSender:
    """A non-blocking UDP socket aimed at one receiver."""

    def __init__(self, host: str, port: int) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.address = (host, port)
        self.socket = socket.socket(family, socket.SOCK_DGRAM)
        self.socket.setblocking(False)

    def send_all(self, datagrams: Sequence[bytes]) -> int:
        """Send each datagram; the count the kernel refused (a full buffer, no route)."""
        lost = 0
        for datagram in datagrams:
            try:
                self.socket.sendto(datagram, self.address)
            except OSError:  # BlockingIOError included: never wait for a receiver
                lost += 1
        return lost

    def close(self) -> None:
        self.socket.close()


def _frame_message(seq: int, t_s: float, ids: Sequence[int]) -> bytes:
    whole = math.floor(t_s)
    micros = min(round((t_s - whole) * 1e6), 999_999)
    return osc.message(
        f"{OSC_PREFIX}/frame", "idiii", [seq & 0x7FFFFFFF, t_s, whole, micros, len(ids)]
    )


def osc_datagrams(frame: FusedFrame, rotations: bool) -> list[bytes]:
    """One fused frame as OSC datagrams (docs/outputs.md, "Address scheme").

    First a bundle with ``/skelfuse/frame`` (seq, fused instant as float64 Unix seconds, the
    same split into whole seconds and microseconds as int32, person count) and
    ``/skelfuse/persons`` (their ids); then per person its bundles: per known joint
    ``/skelfuse/person/<id>/<Joint> x y z confidence`` and, with ``rotations``,
    ``/skelfuse/person/<id>/<Joint>/rot x y z w`` (unknown joints are left out, as the feed's
    ``null``).
    """
    people = persons_json(frame.persons, orientations=ROTATIONS.of(frame) if rotations else None)
    ids = [int(p["id"]) for p in people]  # type: ignore[call-overload]
    head = [_frame_message(frame.seq, frame.t_s, ids)]
    head.append(osc.message(f"{OSC_PREFIX}/persons", "i" * len(ids), ids))
    datagrams = osc.pack_bundles(head)
    for person in people:
        base = f"{OSC_PREFIX}/person/{person['id']}"
        joints: list[Any] = person["joints"]  # type: ignore[assignment]
        confidence: list[float] = person["confidence"]  # type: ignore[assignment]
        turns: list[list[float]] | None = person.get("rotations")  # type: ignore[assignment]
        elements: list[bytes] = []
        for j, name in enumerate(JOINT_NAMES):
            row = joints[j]
            if row is None:
                continue
            elements.append(osc.message(f"{base}/{name}", "ffff", [*row, confidence[j]]))
            if turns is not None:
                elements.append(osc.message(f"{base}/{name}/rot", "ffff", turns[j]))
        datagrams.extend(osc.pack_bundles(elements))
    return datagrams


class OscSink:
    """The OSC output's sink: :func:`osc_datagrams` of each frame to ``host:port``."""

    def __init__(self, host: str, port: int, rotations: bool = False) -> None:
        self.sender = UdpSender(host, port)
        self.rotations = rotations

    def send(self, frame: FusedFrame) -> int:
        return self.sender.send_all(osc_datagrams(frame, self.rotations))

    def close(self) -> None:
        self.sender.close()


def vmc_datagrams(frame: FusedFrame, t_s: float) -> list[bytes]:
    """One fused frame as VMC protocol datagrams: the person with the lowest id as the avatar.

    ``/VMC/Ext/OK 1`` (an avatar is loaded), ``/VMC/Ext/T`` (``t_s``: seconds since the output
    started, float32 as the protocol has it), ``/VMC/Ext/Root/Pos "root"`` at the origin
    unrotated, then a ``/VMC/Ext/Bone/Pos`` per known humanoid bone (:mod:`skelfuse.server.vmc`);
    with nobody fused, OK 0 and the time only.
    """
    head = [osc.message("/VMC/Ext/OK", "i", [1 if frame.persons else 0])]
    head.append(osc.message("/VMC/Ext/T", "f", [t_s]))
    if not frame.persons:
        return osc.pack_bundles(head)
    people = persons_json(frame.persons, orientations=ROTATIONS.of(frame))
    person = min(people, key=lambda p: int(p["id"]))  # type: ignore[call-overload]
    joints = np.array(
        [row if row is not None else [np.nan] * 3 for row in person["joints"]],  # type: ignore[attr-defined]
        dtype=np.float64,
    )
    rotations = np.array(person["rotations"], dtype=np.float64)
    positions, local, known = humanoid_pose(joints, rotations)
    elements = head + [osc.message("/VMC/Ext/Root/Pos", "sfffffff", ["root", 0, 0, 0, 0, 0, 0, 1])]
    for k, (name, _, _) in enumerate(HUMANOID):
        if known[k]:
            values = [float(v) for v in (*positions[k], *local[k])]
            elements.append(osc.message("/VMC/Ext/Bone/Pos", "sfffffff", [name, *values]))
    return osc.pack_bundles(elements)


class VmcSink:
    """The VMC output's sink (a "Performer" sending to a "Marionette", usually port 39539)."""

    def __init__(self, host: str, port: int, clock: Callable[[], float] = time.monotonic) -> None:
        self.sender = UdpSender(host, port)
        self.clock = clock
        self.started = clock()

    def send(self, frame: FusedFrame) -> int:
        return self.sender.send_all(vmc_datagrams(frame, self.clock() - self.started))

    def close(self) -> None:
        self.sender.close()
