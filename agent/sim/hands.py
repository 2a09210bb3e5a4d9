"""Plausible Kinect v2 hand states for the simulator, from the joints the sensor reports.

The real classifier looks at the hand's depth pixels; the simulator has none, so it makes up
states that follow the pose, enough for a viewer or an avatar to show something sensible:

- a hand whose wrist or hand joint is not TRACKED: NotTracked, Low confidence;
- a hand within :data:`NEAR_CENTRE_M` of the body's centre (SpineMid): Closed, High (a fist
  held at the chest);
- a hand raised above its shoulder: Open, High, except for about one second in
  :data:`LASSO_EVERY_S` (a different second for each body and hand) when it shows Lasso;
- any other hand (hanging at the side): Open, Low.

Deterministic (no random draws): the same joints and time give the same states, and turning
hand states on or off changes nothing else the simulator sends.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.hands import HandConfidence, Hands, HandState
from skelfuse.protocol.skeleton import JointId, TrackingState

NEAR_CENTRE_M: Final = 0.25
LASSO_EVERY_S: Final = 20.0

# (wrist, hand, shoulder) of the body's left and right hand.
_SIDES: Final = (
    (JointId.WRIST_LEFT, JointId.HAND_LEFT, JointId.SHOULDER_LEFT),
    (JointId.WRIST_RIGHT, JointId.HAND_RIGHT, JointId.SHOULDER_RIGHT),
)


def simulated_hands(
    joints_m: npt.NDArray[np.float32], states: npt.NDArray[np.uint8], tracking_id: int, t_s: float
) -> Hands:
    """The hand states a Kinect v2 might report for this body.

    Args:
        joints_m: (25, 3) float32, metres, the sensor frame (+Y up), as sent.
        states: (25,) uint8 TrackingState, as sent.
        tracking_id: the body's id (chooses when it shows Lasso).
        t_s: the capture instant, seconds.
    """
    result: list[tuple[HandState, HandConfidence]] = []
    for side, (wrist, hand, shoulder) in enumerate(_SIDES):
        if states[wrist] != TrackingState.TRACKED or states[hand] != TrackingState.TRACKED:
            result.append((HandState.NOT_TRACKED, HandConfidence.LOW))
            continue
        centre = joints_m[JointId.SPINE_MID]
        if float(np.linalg.norm(joints_m[hand] - centre)) < NEAR_CENTRE_M:
            result.append((HandState.CLOSED, HandConfidence.HIGH))
        elif joints_m[hand, 1] > joints_m[shoulder, 1]:
            phase = (tracking_id * 7 + side * 11) % int(LASSO_EVERY_S)
            lasso = int(t_s) % int(LASSO_EVERY_S) == phase
            result.append((HandState.LASSO if lasso else HandState.OPEN, HandConfidence.HIGH))
        else:
            result.append((HandState.OPEN, HandConfidence.LOW))
    (left, left_confidence), (right, right_confidence) = result
    return Hands(left, right, left_confidence, right_confidence)
