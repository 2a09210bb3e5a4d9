"""Messages apps receive on the WebSocket feed: fused frames and persons as JSON-ready dicts.

The one builder of these messages (docs/api.md), used by the live server and by offline replay.
NaN never leaves the server: unknown joints become ``null``. Tracking ids become strings because
a uint64 does not fit a JavaScript number. The builder reads the fusion results through the small
protocols below, so this layer does not import the fusion layer that produces them.

Two additions leave the default message's bytes as they were: a person's (and a raw body's)
``hands`` only where a sensor reports hand states, and joint rotations only for clients that
ask for them (``orientations``, computed by the server: ``recording/joint_orientations.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.hands import Hands

FEED_VERSION: Final = 1
"""The ``v`` of every feed message."""


class FeedPerson(Protocol):
    """What a fused person message is built from (``skelfuse.fusion.views.FusedPerson``).

    joints: (25, 3) metres, world frame, NaN where unknown.
    confidence: (25,) in [0, 1].
    joint_sources: (25,) bitmask per joint: bit k set when ``sources[k]`` contributed.
    mirrored: the sensors whose view of this person was swapped back (left ↔ right).
    """

    @property
    def person_id(self) -> int: ...
    @property
    def joints(self) -> npt.NDArray[np.floating]: ...
    @property
    def confidence(self) -> npt.NDArray[np.floating]: ...
    @property
    def sources(self) -> Sequence[str]: ...
    @property
    def joint_sources(self) -> npt.NDArray[np.integer]: ...
    @property
    def mirrored(self) -> Sequence[str]: ...
    @property
    def hands(self) -> Hands | None: ...


class FeedOrientations(Protocol):
    """Joint rotations of a frame's persons, in the frame's person order
    (``skelfuse.recording.joint_orientations.Orientations``).

    world, local: (P, 25, 4) unit quaternions ``(x, y, z, w)``.
    rest_offsets: (P, 25, 3) metres.
    """

    @property
    def world(self) -> npt.NDArray[np.floating]: ...
    @property
    def local(self) -> npt.NDArray[np.floating]: ...
    @property
    def rest_offsets(self) -> npt.NDArray[np.floating]: ...


QUATERNION_DECIMALS: Final = 5
"""Rotations are sent to 1e-5 (about 0.001°): along the longest chain, SpineBase to a hand tip
(nine bones, about 1.5 m), that moves the tip by at most about 0.1 mm."""


class FeedView(Protocol):
    """One sensor's body in the world frame (``skelfuse.fusion.views.View``).

    joints_world: (25, 3) metres, world frame, NaN where not tracked.
    states: (25,) TrackingState values.
    """

    @property
    def sensor_id(self) -> str: ...
    @property
    def tracking_id(self) -> int: ...
    @property
    def joints_world(self) -> npt.NDArray[np.floating]: ...
    @property
    def states(self) -> npt.NDArray[np.uint8]: ...
    @property
    def hands(self) -> Hands | None: ...


class FeedFrame(Protocol):
    """One fusion step's result (``skelfuse.fusion.engine.FusedFrame``); ``t_s`` in Unix seconds.

    extrapolated: ``(sensor_id, seconds)`` per sensor extrapolated to ``t_s`` (late at the
    ``deadline`` alignment's deadline); empty when every sensor was interpolated.
    """

    @property
    def seq(self) -> int: ...
    @property
    def t_s(self) -> float: ...
    @property
    def persons(self) -> Sequence[FeedPerson]: ...
    @property
    def raw(self) -> Sequence[FeedView]: ...
    @property
    def extrapolated(self) -> Sequence[tuple[str, float]]: ...


def joints_json(joints: npt.NDArray[np.floating], decimals: int = 4) -> list[list[float] | None]:
    """(J, 3) metres → J rows ``[x, y, z]`` rounded to ``decimals``; ``None`` where not finite."""
    rounded = np.round(np.asarray(joints, dtype=np.float64), decimals).reshape(-1, 3)
    finite: list[bool] = np.asarray(np.isfinite(rounded).all(axis=1)).tolist()
    # One tolist for the whole array, not one per row: the feed builds 150 rows a frame.
    rows: list[list[float]] = rounded.tolist()
    return [row if ok else None for row, ok in zip(rows, finite, strict=True)]


def round_like_python(values: npt.NDArray[np.float64], decimals: int) -> npt.NDArray[np.float64]:
    """``round(v, decimals)`` of every value, as Python's ``round`` gives it, vectorised.

    Python rounds the exact binary value (correctly rounded); ``rint(v · 10^d) / 10^d`` agrees
    except where ``v · 10^d`` lies within a hair of a half, because the product is itself
    rounded: 0.0025 is 0.00250000000000000005…, which Python rounds up to 0.003, while
    ``rint(2.5)`` gives 2. Those few values are rounded by Python itself. Finite values of
    magnitude up to about 10^6 / 10^d (confidences, not Unix times).
    """
    scale = 10.0**decimals
    scaled = values * scale
    out: npt.NDArray[np.float64] = np.rint(scaled) / scale
    near_half = np.abs(scaled - np.floor(scaled) - 0.5) < 1e-6
    for i in np.flatnonzero(near_half):
        out.flat[i] = round(float(values.flat[i]), decimals)
    return out


def hands_json(hands: Hands) -> dict[str, object]:
    """One body's hand states: per hand (the person's left and right) its state and confidence,
    by name (``open``, ``closed``, ``lasso``, ``unknown``, ``not_tracked``; ``high``, ``low``)."""
    return {
        side: {"state": state.name.lower(), "confidence": confidence.name.lower()}
        for side, state, confidence in (
            ("left", hands.left, hands.left_confidence),
            ("right", hands.right, hands.right_confidence),
        )
    }


def _rows(values: npt.NDArray[np.floating], decimals: int) -> list[list[list[float]]]:
    """(P, J, K) numbers rounded, as nested lists (no ``-0.0``)."""
    rows: list[list[list[float]]] = (np.round(values.astype(np.float64), decimals) + 0.0).tolist()
    return rows


def persons_json(
    persons: Sequence[FeedPerson],
    decimals: int = 4,
    orientations: FeedOrientations | None = None,
) -> list[dict[str, object]]:
    """Fused persons as apps receive them: NaN never leaves the server (null instead).

    Confidence is 0 exactly where the joint is null (docs/api.md): a joint that is present but
    only barely trusted is sent as 0.001, not rounded away to 0. The rounding runs once over
    every person of the frame (numpy calls, not one Python call per number), and gives the
    numbers ``round`` gave person by person.

    Args:
        persons: the frame's fused persons.
        decimals: of the joint positions (metres).
        orientations: the persons' joint rotations, in the same order, for a client that asked
            for them (``rotations``, ``local_rotations``, ``rest_offsets``); None leaves them out.
    """
    if not persons:
        return []
    joints = np.array([p.joints for p in persons], dtype=np.float64).reshape(len(persons), -1, 3)
    rounded = np.round(joints, decimals)  # (P, J, 3)
    finite = np.asarray(np.isfinite(rounded).all(axis=2))  # (P, J)
    confidence = np.array([p.confidence for p in persons], dtype=np.float64)
    sent_confidence = np.where(finite, np.maximum(round_like_python(confidence, 3), 0.001), 0.0)
    all_rows: list[list[list[float] | None]] = rounded.tolist()
    # Few joints are unknown: blank those rows in place rather than test all P·J rows in Python.
    if not finite.all():
        joint_count = finite.shape[1]
        for flat in np.flatnonzero(~finite).tolist():
            all_rows[flat // joint_count][flat % joint_count] = None
    all_confidence: list[list[float]] = sent_confidence.tolist()
    out: list[dict[str, object]] = []
    for person, rows, conf in zip(persons, all_rows, all_confidence, strict=True):
        message: dict[str, object] = {
            "id": person.person_id,
            "joints": rows,
            "confidence": conf,
            "sources": list(person.sources),
            # Per joint, bit k set when sources[k] contributed (≥ 5 % of its weight).
            "joint_sources": np.asarray(person.joint_sources).tolist(),
            "mirrored": list(person.mirrored),
        }
        if person.hands is not None:  # only where a sensor reports them: others' bytes as before
            message["hands"] = hands_json(person.hands)
        out.append(message)
    if orientations is not None:
        world = _rows(orientations.world, QUATERNION_DECIMALS)
        local = _rows(orientations.local, QUATERNION_DECIMALS)
        offsets = _rows(orientations.rest_offsets, decimals)
        for k, message in enumerate(out):
            message["rotations"] = world[k]
            message["local_rotations"] = local[k]
            message["rest_offsets"] = offsets[k]
    return out


def person_json(person: FeedPerson, decimals: int = 4) -> dict[str, object]:
    """One fused person as apps receive it (:func:`persons_json` of one)."""
    return persons_json([person], decimals)[0]


def view_json(view: FeedView, decimals: int = 4) -> dict[str, object]:
    """One sensor's body as sent in a frame's ``raw`` list."""
    message: dict[str, object] = {
        "sensor": view.sensor_id,
        "tracking_id": str(view.tracking_id),  # uint64 does not fit a JavaScript number
        "joints": joints_json(view.joints_world, decimals),
        "states": np.asarray(view.states).tolist(),
    }
    if view.hands is not None:
        message["hands"] = hands_json(view.hands)
    return message


def frame_json(
    frame: FeedFrame,
    include_raw: bool,
    sent_at_s: float | None = None,
    orientations: FeedOrientations | None = None,
) -> dict[str, object]:
    """A fused frame message.

    Args:
        frame: the fused frame.
        include_raw: add every sensor's bodies (``raw``), for clients that asked for them.
        sent_at_s: the server's wall clock when sending (Unix seconds), sent as ``t_sent``; None
            leaves ``t_sent`` out, as offline replay does so that its output is deterministic.
        orientations: the persons' joint rotations (in ``frame.persons`` order), for clients
            that asked for them; None leaves them out.
    """
    message: dict[str, object] = {
        "type": "frame",
        "v": FEED_VERSION,
        "seq": frame.seq,
        "t": round(frame.t_s, 6),
    }
    if sent_at_s is not None:
        message["t_sent"] = round(sent_at_s, 6)
    message["persons"] = persons_json(frame.persons, orientations=orientations)
    if frame.extrapolated:  # only then: frames fused with every sensor on time stay as before
        message["extrapolated"] = {sensor: round(s, 4) for sensor, s in frame.extrapolated}
    if include_raw:
        message["raw"] = [view_json(v) for v in frame.raw]
    return message
