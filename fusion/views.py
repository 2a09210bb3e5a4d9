"""What fusion works on and gives out: one sensor's body at an instant, one fused person.

Shapes: 25 joints (Kinect v2 order, :mod:`skelfuse.protocol.skeleton`); metres, world frame
(right-handed, +Y up, floor at y = 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Final, cast

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.hands import fuse_hands
from skelfuse.protocol.hands import Hands
from skelfuse.protocol.skeleton import JOINT_COUNT

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(slots=True)
class View:
    """One sensor's body at the fusion instant (read-only by convention: not frozen, because a
    frozen dataclass's ``__init__`` costs 2.4 µs against 0.5, and a step builds one per body).

    joints_world: (25, 3) float64, metres, world frame, NaN where NotTracked.
    states: (25,) uint8 TrackingState.
    sensor_position: (3,) float64, where the sensor stands in the world (metres), if known.
    sensor_type: what the sensor's agent announced (``protocol.wire.SENSOR_TYPES``); selects
        the view's :class:`fusion.priors.SensorPrior`.
    hands: the sensor's hand states for this body (nearest frame), None if it reports none.
    """

    sensor_id: str
    tracking_id: int
    joints_world: FloatArray
    states: npt.NDArray[np.uint8]
    sensor_position: FloatArray | None = None
    sensor_type: str = "kinect_v2"
    hands: Hands | None = None


@dataclass(frozen=True, slots=True)
class FusedPerson:
    """One person's fused skeleton (world frame, metres; NaN and confidence 0 where unknown).

    joint_sources: (25,) int64 bitmask per joint: bit k set when ``sources[k]`` contributed at
        least 5 % of that joint's weight.
    mirrored: the sensors whose view of this person was swapped back (left ↔ right).
    hands: one hand state per hand (the rule of :mod:`fusion.hands`); None when no view of
        this person reports hand states.
    """

    person_id: int
    joints: FloatArray
    confidence: FloatArray
    sources: tuple[str, ...]
    views: tuple[View, ...]
    joint_sources: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros(JOINT_COUNT, dtype=np.int64)
    )
    mirrored: tuple[str, ...] = ()
    hands: Hands | None = None


_new_object = object.__new__
# The slots' own setters: a frozen dataclass's __init__ goes through object.__setattr__ once per
# field (2.3 µs a person, a third of building the step's output), as protocol.messages notes.
_SETTERS: Final = tuple(
    cast(Any, getattr(FusedPerson, name)).__set__
    for name in (
        "person_id", "joints", "confidence", "sources", "views", "joint_sources", "mirrored",
        "hands",
    )
)  # fmt: skip


def _fused_person(*values: object) -> FusedPerson:
    """``FusedPerson(*values)`` (every field, in order) for values built here: the same frozen
    object, in half the time (there are no post-init checks)."""
    person: FusedPerson = _new_object(FusedPerson)
    for setter, value in zip(_SETTERS, values, strict=True):
        setter(person, value)
    return person


_SOURCES_KEPT: Final = 64
"""Layouts of views' sensors :func:`_sources_and_slots` keeps."""
SensorLayout = tuple[int, tuple[tuple[str, ...], ...]]
"""The widest person's view count, and each person's views' sensor ids in order."""
_sources_of: dict[SensorLayout, tuple[list[tuple[str, ...]], IntArray]] = {}


def _sources_and_slots(
    sensor_ids: tuple[tuple[str, ...], ...], widest: int
) -> tuple[list[tuple[str, ...]], IntArray]:
    """Per person its sources (sensor ids sorted, once each) and, (A, widest), each view's
    place among them (0 on padding). Steps repeat the same sensors per person: kept per layout
    (read-only arrays)."""
    key = (widest, sensor_ids)
    kept = _sources_of.get(key)
    if kept is None:
        if len(_sources_of) >= _SOURCES_KEPT:
            _sources_of.clear()
        sources = [tuple(sorted(set(own))) for own in sensor_ids]
        slots = np.array(
            [
                [found.index(sensor) for sensor in own] + [0] * (widest - len(own))
                for own, found in zip(sensor_ids, sources, strict=True)
            ],
            dtype=np.int64,
        ).reshape(len(sensor_ids), widest)
        slots.flags.writeable = False
        kept = _sources_of[key] = (sources, slots)
    return kept


def fused_persons(
    person_ids: list[int],
    joints: list[FloatArray],
    confidence: FloatArray,
    views: list[list[View]],
    carried: npt.NDArray[np.bool_],
    mirrored: list[list[bool]],
) -> list[FusedPerson]:
    """The fused persons as apps receive them, with which sensors carried each joint.

    Args:
        person_ids, joints, views, mirrored: per person: its id, (25, 3) skeleton, views and
            whether each view was mirrored. confidence: (A, 25). carried: (A, widest, 25)
            whether each view (padded to the widest person) carried each joint.
    """
    sources, slots = _sources_and_slots(
        tuple(tuple(v.sensor_id for v in own) for own in views), carried.shape[1]
    )
    # Each view's bit where it carried the joint, all persons at once (padding carries none).
    joint_sources = np.bitwise_or.reduce(carried.astype(np.int64) << slots[..., None], axis=1)
    # fuse_hands gives None when no view reports hand states: most rigs, so asked once.
    with_hands = any(v.hands is not None for own in views for v in own)
    return [
        _fused_person(
            person_id,
            skeleton,
            confidence[a],
            sources[a],
            tuple(views[a]),
            joint_sources[a],
            tuple(sorted(v.sensor_id for v, m in zip(views[a], mirrored[a], strict=True) if m))
            if any(mirrored[a])
            else (),
            fuse_hands([(v.hands, v.states, m) for v, m in zip(views[a], mirrored[a], strict=True)])
            if with_hands
            else None,
        )
        for a, (person_id, skeleton) in enumerate(zip(person_ids, joints, strict=True))
    ]
