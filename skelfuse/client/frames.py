"""The feed's messages as typed Python objects (docs/api.md, "WebSocket `/ws/skeletons`").

Positions are numpy arrays with NaN where the feed sends ``null``, so that apps index joints by
:class:`~skelfuse.protocol.skeleton.JointId` and do arithmetic without testing for None.
Every field the docs list has an attribute; a key the docs do not list yet is kept in
``extra``, so a newer server's additions are not lost.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Skeleton:
    """The first message: the joint set and its hierarchy (also ``GET /api/skeleton``)."""

    name: str
    joints: tuple[str, ...]
    parents: tuple[int, ...]
    """Parent index of each joint; -1 for the root."""
    bones: tuple[tuple[int, int], ...]
    units: str
    up: str
    handedness: str


@dataclass(frozen=True, slots=True)
class HandState:
    """One hand: ``state`` is ``open``, ``closed``, ``lasso``, ``unknown`` or ``not_tracked``;
    ``confidence`` is ``high`` or ``low``."""

    state: str
    confidence: str


@dataclass(frozen=True, slots=True)
class Hands:
    """A body's hands, the person's left and right (Kinect v2 sensors only)."""

    left: HandState
    right: HandState


@dataclass(frozen=True, slots=True)
class Rotations:
    """A person's joint rotations (docs/api.md, "Rotations"), sent to clients that ask.

    world: (25, 4) unit quaternions ``(x, y, z, w)``: each joint's bone (parent → joint)
        relative to the rest pose, in the world frame.
    local: (25, 4) the same relative to the parent joint's (the root's is its world one).
    rest_offsets: (25, 3) metres: each joint's offset from its parent in the rest pose.
    """

    world: F64
    local: F64
    rest_offsets: F64


@dataclass(frozen=True, slots=True)
class Person:
    """One fused person.

    joints: (25, 3) metres, world frame, NaN where no sensor has the joint.
    confidence: (25,) in [0, 1], 0 where the joint is unknown.
    joint_sources: per joint, bit k set when ``sources[k]`` contributed.
    """

    id: int
    joints: F64
    confidence: F64
    sources: tuple[str, ...]
    joint_sources: tuple[int, ...]
    mirrored: tuple[str, ...]
    hands: Hands | None = None
    rotations: Rotations | None = None


@dataclass(frozen=True, slots=True)
class RawBody:
    """One sensor's own body in the world frame (frames of a client that asked for ``raw``).

    joints: (25, 3) metres, NaN where not tracked. states: per joint 0 NotTracked, 1 Inferred,
    2 Tracked.
    """

    sensor: str
    tracking_id: int
    joints: F64
    states: tuple[int, ...]
    hands: Hands | None = None


@dataclass(frozen=True, slots=True)
class Frame:
    """One fused frame.

    t: capture instant (Unix seconds, the server's clock); t_sent: when the server sent it;
    received: when this client read it (its own wall clock, before decoding).
    extrapolated: per sensor carried forward to ``t`` at the deadline, seconds.
    """

    seq: int
    t: float
    t_sent: float | None
    persons: tuple[Person, ...]
    raw: tuple[RawBody, ...] = ()
    extrapolated: Mapping[str, float] = field(default_factory=dict)
    received: float | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)


_FRAME_KEYS = frozenset({"type", "v", "seq", "t", "t_sent", "persons", "raw", "extrapolated"})


def decode(message: str | bytes) -> dict[str, Any]:
    """One WebSocket message as a dict: JSON text, or msgpack bytes.

    Raises:
        ValueError: the message is neither (or not a JSON/msgpack map).
    """
    try:
        data = json.loads(message) if isinstance(message, str) else msgpack.unpackb(message)
    except (ValueError, msgpack.UnpackException) as exc:
        raise ValueError(f"not a feed message: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError("not a feed message: not a map")
    return data


def points(rows: Sequence[Sequence[float] | None], width: int = 3) -> F64:
    """Rows of numbers with ``null`` for unknown → (N, width) float64 with NaN rows."""
    gap = [np.nan] * width
    array: F64 = np.array([gap if row is None else row for row in rows], dtype=np.float64)
    return array.reshape(len(rows), width)


def skeleton_from(data: Mapping[str, Any]) -> Skeleton:
    """The skeleton message.

    Raises:
        ValueError: not a skeleton message.
    """
    if data.get("type") != "skeleton":
        raise ValueError(f"expected the skeleton message first, got type {data.get('type')!r}")
    return Skeleton(
        name=data["name"],
        joints=tuple(data["joints"]),
        parents=tuple(data["parents"]),
        bones=tuple((int(a), int(b)) for a, b in data["bones"]),
        units=data["units"],
        up=data["up"],
        handedness=data["handedness"],
    )


def _hands(data: Mapping[str, Any] | None) -> Hands | None:
    if data is None:
        return None
    left, right = data["left"], data["right"]
    return Hands(
        HandState(left["state"], left["confidence"]),
        HandState(right["state"], right["confidence"]),
    )


def person_from(data: Mapping[str, Any]) -> Person:
    """One entry of a frame's ``persons`` (or of ``GET /api/persons``)."""
    rotations = None
    if "rotations" in data:
        rotations = Rotations(
            points(data["rotations"], 4),
            points(data["local_rotations"], 4),
            points(data["rest_offsets"]),
        )
    return Person(
        id=int(data["id"]),
        joints=points(data["joints"]),
        confidence=np.asarray(data["confidence"], dtype=np.float64),
        sources=tuple(data["sources"]),
        joint_sources=tuple(data["joint_sources"]),
        mirrored=tuple(data.get("mirrored", ())),
        hands=_hands(data.get("hands")),
        rotations=rotations,
    )


def raw_body_from(data: Mapping[str, Any]) -> RawBody:
    """One entry of a frame's ``raw``."""
    return RawBody(
        sensor=data["sensor"],
        tracking_id=int(data["tracking_id"]),
        joints=points(data["joints"]),
        states=tuple(data["states"]),
        hands=_hands(data.get("hands")),
    )


def frame_from(data: Mapping[str, Any], received: float | None = None) -> Frame:
    """A frame message (``received``: the client's wall clock when it read it).

    Raises:
        ValueError: not a frame message.
    """
    if data.get("type") != "frame":
        raise ValueError(f"not a frame message: type {data.get('type')!r}")
    return Frame(
        seq=int(data["seq"]),
        t=float(data["t"]),
        t_sent=data.get("t_sent"),
        persons=tuple(person_from(p) for p in data["persons"]),
        raw=tuple(raw_body_from(b) for b in data.get("raw", ())),
        extrapolated=dict(data.get("extrapolated", {})),
        received=received,
        extra={k: v for k, v in data.items() if k not in _FRAME_KEYS},
    )
