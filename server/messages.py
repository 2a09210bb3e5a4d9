"""Messages apps receive: fused frames and persons as JSON-ready dicts (docs/api.md).

NaN never leaves the server: unknown joints become ``null``. Tracking ids become strings because
a uint64 does not fit a JavaScript number.
"""

from __future__ import annotations

import time

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.hub import FusedFrame
from skelfuse.fusion.tracking import FusedPerson, View


def person_json(person: FusedPerson, decimals: int = 4) -> dict[str, object]:
    """A fused person as apps receive it: NaN never leaves the server (null instead).

    Confidence is 0 exactly where the joint is null (docs/api.md): a joint that is present but
    only barely trusted is sent as 0.001, not rounded away to 0.
    """
    joints = joints_json(person.joints, decimals)
    confidence = [
        0.0 if joint is None else max(round(float(c), 3), 0.001)
        for joint, c in zip(joints, person.confidence, strict=True)
    ]
    return {
        "id": person.person_id,
        "joints": joints,
        "confidence": confidence,
        "sources": list(person.sources),
        # Per joint, bit k set when sources[k] contributed (≥ 5 % of the joint's weight).
        "joint_sources": [int(m) for m in person.joint_sources],
        "mirrored": list(person.mirrored),
    }


def joints_json(joints: npt.NDArray[np.floating], decimals: int = 4) -> list[list[float] | None]:
    rounded = np.round(np.asarray(joints, dtype=np.float64), decimals).reshape(-1, 3)
    finite = np.isfinite(rounded).all(axis=1).reshape(-1)
    return [row.tolist() if finite[i] else None for i, row in enumerate(rounded)]


def view_json(view: View, decimals: int = 4) -> dict[str, object]:
    return {
        "sensor": view.sensor_id,
        "tracking_id": str(view.tracking_id),  # uint64 does not fit a JavaScript number
        "joints": joints_json(view.joints_world, decimals),
        "states": [int(s) for s in view.states],
    }


def frame_json(frame: FusedFrame, include_raw: bool) -> dict[str, object]:
    message: dict[str, object] = {
        "type": "frame",
        "v": 1,
        "seq": frame.seq,
        "t": round(frame.t_s, 6),
        "t_sent": round(time.time(), 6),
        "persons": [person_json(p) for p in frame.persons],
    }
    if include_raw:
        message["raw"] = [view_json(v) for v in frame.raw]
    return message
