"""Hand states: the optional ``hands`` key of a body on the wire (docs/protocol.md §7.4).

Kinect v2 classifies each tracked body's hands as open, closed or "lasso" (two fingers out),
each with a Low/High confidence (Kinect for Windows SDK 2.0 ``HandState`` and
``TrackingConfidence``; PyKinect2's ``body.hand_left_state`` and ``body.hand_left_confidence``).
Azure Kinect and Orbbec Femto Body Tracking have no hand states: their agents omit the key.

On the wire a body MAY carry ``hands``: an array of four ints ``[left_state, right_state,
left_confidence, right_confidence]`` (the person's left and right, as the joints). An agent
that knows nothing about hands omits the key (every v1 agent before it did), and a server that
knows nothing about it ignores it (unknown keys are ignored), so the key is compatible both ways
within protocol v1.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final, NamedTuple

from skelfuse.protocol.errors import DecodeError


class HandState(IntEnum):
    """Kinect v2 ``HandState``, by value."""

    UNKNOWN = 0
    NOT_TRACKED = 1
    OPEN = 2
    CLOSED = 3
    LASSO = 4


class HandConfidence(IntEnum):
    """Kinect v2 ``TrackingConfidence`` of a hand state, by value."""

    LOW = 0
    HIGH = 1


class Hands(NamedTuple):
    """One body's two hand states (the person's left and right) and their confidences."""

    left: HandState
    right: HandState
    left_confidence: HandConfidence
    right_confidence: HandConfidence

    def to_wire(self) -> list[int]:
        """The ``hands`` array as the reference encoder writes it: four small ints."""
        return [int(self.left), int(self.right), int(self.left_confidence),
                int(self.right_confidence)]  # fmt: skip


UNKNOWN_HANDS: Final = Hands(
    HandState.UNKNOWN, HandState.UNKNOWN, HandConfidence.LOW, HandConfidence.LOW
)
"""What a sensor that reports hand states says when it cannot tell."""

_STATES: Final = tuple(HandState)  # indexing beats HandState(value) on the decode path
_CONFIDENCES: Final = tuple(HandConfidence)


def hands_from_sdk(state_left: int, state_right: int, high_left: int, high_right: int) -> Hands:
    """Hands from an SDK's raw enum values; values outside the enums become Unknown / Low."""
    return Hands(
        _STATES[state_left] if 0 <= state_left < len(_STATES) else HandState.UNKNOWN,
        _STATES[state_right] if 0 <= state_right < len(_STATES) else HandState.UNKNOWN,
        HandConfidence.HIGH if high_left == HandConfidence.HIGH else HandConfidence.LOW,
        HandConfidence.HIGH if high_right == HandConfidence.HIGH else HandConfidence.LOW,
    )


def hands_quickly(value: object) -> Hands | None:
    """A valid ``hands`` array's value, or None for "not sure" (the bulk path's check).

    Raises nothing; None also for an absent key, so callers test ``"hands" in body`` first.
    """
    if type(value) is not list or len(value) != 4:
        return None
    left, right, left_high, right_high = value
    if (
        type(left) is not int
        or type(right) is not int
        or type(left_high) is not int
        or type(right_high) is not int
        or not 0 <= left <= 4
        or not 0 <= right <= 4
        or not 0 <= left_high <= 1
        or not 0 <= right_high <= 1
    ):
        return None
    return Hands(_STATES[left], _STATES[right], _CONFIDENCES[left_high], _CONFIDENCES[right_high])


def check_hands(value: object, index: int) -> Hands | None:
    """Body ``index``'s ``hands`` value checked in the documented order; None for absent/nil.

    Raises:
        DecodeError: ``bad_shape`` (not an array of 4), ``bad_field`` (an element that is not an
            int; a bool is not an int here) or ``out_of_range`` (a state outside 0..4, a
            confidence outside 0..1).
    """
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != 4:
        raise DecodeError(
            "bad_shape",
            f"body {index}: hands must be [left_state, right_state, left_confidence, "
            "right_confidence] or nil",
        )
    for name, item in zip(("left_state", "right_state", "left_confidence", "right_confidence"),
                          value, strict=True):  # fmt: skip
        if type(item) is not int:
            raise DecodeError(
                "bad_field", f"body {index}: hands {name} must be an int, got {type(item).__name__}"
            )
    left, right, left_high, right_high = value
    if not (0 <= left <= 4 and 0 <= right <= 4):
        raise DecodeError("out_of_range", f"body {index}: hand state {left}, {right} not in 0..4")
    if not (0 <= left_high <= 1 and 0 <= right_high <= 1):
        raise DecodeError(
            "out_of_range", f"body {index}: hand confidence {left_high}, {right_high} not in 0..1"
        )
    return Hands(_STATES[left], _STATES[right], _CONFIDENCES[left_high], _CONFIDENCES[right_high])
