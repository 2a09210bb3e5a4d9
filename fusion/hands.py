"""One hand state per hand of a fused person, from the views that report them (Kinect v2 only).

The rule, per hand (the person's left, then right):

1. Each view whose sensor reports hand states votes with its state for that hand, but only if
   the view's wrist of that hand is TRACKED (a hand state over an inferred wrist is a guess) and
   the state is Open, Closed or Lasso (Unknown and NotTracked carry no vote). A view that fusion
   mirrored (its left and right swapped back, :mod:`fusion.mirror`) votes its left hand's state
   for the person's right hand, and the other way round.
2. The state with the most votes wins; a tie goes to the state with more High-confidence votes,
   then to the lower ``HandState`` value (Open before Closed before Lasso), so the result never
   depends on view order.
3. The fused confidence is High when at least one winning vote is High, else Low.
4. No vote: Unknown with Low confidence.

A person none of whose views reports hand states (Azure Kinect, Femto, older agents, the
recorded takes of the golden tests) gets no hand states at all (None), so nothing changes for
them. A view's hand states are those of the sensor frame nearest the fused instant (states are
not interpolated); a sensor extrapolated to a deadline contributes none at that instant.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.hands import UNKNOWN_HANDS, HandConfidence, Hands, HandState
from skelfuse.protocol.skeleton import JointId, TrackingState

_VOTING: frozenset[HandState] = frozenset({HandState.OPEN, HandState.CLOSED, HandState.LASSO})
_WRIST_LEFT = int(JointId.WRIST_LEFT)
_WRIST_RIGHT = int(JointId.WRIST_RIGHT)

HandReport = tuple[Hands | None, npt.NDArray[np.uint8], bool]
"""One view's hand states (None: its sensor reports none), its (25,) tracking states in the
sensor's own labelling, and whether fusion mirrored it."""


def fuse_hands(reports: Sequence[HandReport]) -> Hands | None:
    """The person's hand states by the rule above; None when no view reports any."""
    if all(hands is None for hands, _, _ in reports):
        return None
    left: list[tuple[HandState, HandConfidence]] = []
    right: list[tuple[HandState, HandConfidence]] = []
    for hands, states, mirrored in reports:
        if hands is None:
            continue
        # The sensor's own left hand, wrist and all; a mirrored view's left is the person's right.
        own_left = (hands.left, hands.left_confidence, states[_WRIST_LEFT])
        own_right = (hands.right, hands.right_confidence, states[_WRIST_RIGHT])
        for (state, confidence, wrist), votes in zip(
            (own_left, own_right), (right, left) if mirrored else (left, right), strict=True
        ):
            if wrist == TrackingState.TRACKED and state in _VOTING:
                votes.append((state, confidence))
    left_state, left_confidence = _winner(left)
    right_state, right_confidence = _winner(right)
    return Hands(left_state, right_state, left_confidence, right_confidence)


def _winner(votes: list[tuple[HandState, HandConfidence]]) -> tuple[HandState, HandConfidence]:
    if not votes:
        return UNKNOWN_HANDS.left, UNKNOWN_HANDS.left_confidence
    tally = {
        state: (
            sum(1 for s, _ in votes if s == state),
            sum(1 for s, c in votes if s == state and c == HandConfidence.HIGH),
        )
        for state in {s for s, _ in votes}
    }
    state = max(tally, key=lambda s: (tally[s][0], tally[s][1], -int(s)))
    confidence = HandConfidence.HIGH if tally[state][1] else HandConfidence.LOW
    return state, confidence
