"""Mutual capture fused by the production :class:`~skelfuse.server.hub.FusionHub` (the server's
moving-sensor support): part (b) of bench/moving/sensors.py with ``--fusion server``.

Each wearer's sensor registers as moving in the tracking space ``room`` with the identity as
the space's world transform (a ``sim_truth`` hint) and starts at a random phase of its 30 fps
clock; its frames go to the hub as wire bytes (bodies in the sensor frame, the headset's pose
attached) 2 ms after capture, the hub fusing on its default settings and output grid as the
live loop does. Fused persons are matched to the truth as the accuracy benchmark does
(:class:`bench.accuracy.metrics.Log`: trunk distance, Hungarian, 1 m gate).

With ``spaces`` (:mod:`bench.moving.spaces`, ``--spaces per-wearer``) each wearer's
sensor is in its own space ``quest-k`` instead, its frames' poses given in it, the hub knowing
the spaces from that calibration only (no hint), and the fused persons moved by its gauge onto
the truth's world before they are scored.
"""

from __future__ import annotations

import numpy as np

from bench.accuracy.metrics import Log
from bench.moving.fused import FPS, FusedCase
from bench.moving.spaces import Spaces, space_id
from skelfuse.fusion.settings import HubSettings
from skelfuse.protocol.sensor_pose import pose_from_matrix, pose_matrix
from skelfuse.protocol.transform import apply, invert
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.hub import FusionHub

T0 = 1_800_000_000.0
NETWORK_DELAY_S = 0.002


def _names(count: int) -> list[str]:
    return [f"head-{i}" for i in range(count)]


def new_hub(
    count: int, settings: HubSettings | None = None, spaces: Spaces | None = None
) -> FusionHub:
    """A hub with ``count`` moving sensors ``head-i`` registered in the space ``room`` (the
    identity hinted as its world transform), or each in its own space of ``spaces``."""
    hub = FusionHub(settings or HubSettings(), spaces.calibration if spaces else None)
    for k, name in enumerate(_names(count)):
        if spaces is not None:
            hello = Hello(name, "sim", "bench", FPS, 0, moving=True, pose_space=space_id(k))
        else:
            hello = Hello(
                name,
                "sim",
                "bench",
                FPS,
                0,
                pose_hint=np.eye(4),
                pose_hint_source="sim_truth",
                moving=True,
                pose_space="room",
            )
        hub.handle_message(name.encode(), [encode(hello)], T0, 0.0)
    return hub


def hub_errors(case: FusedCase, spaces: Spaces | None = None) -> dict[str, float]:
    """MPJPE, per-joint median (mm), coverage and erroneous share of the hub's fused persons
    (``spaces``: see the module docstring)."""
    capture = case.capture()
    rng = np.random.default_rng(case.seed + 77)
    names = _names(capture.wearer_count)
    events = sorted(
        (phase + n / FPS, w)
        for w, phase in enumerate(rng.uniform(0.0, 1.0 / FPS, size=capture.wearer_count))
        for n in range(round(case.duration_s * FPS))
    )
    hub = new_hub(capture.wearer_count, spaces=spaces)
    space_from_world = [invert(w) for w in spaces.world_from_space] if spaces else None
    log = Log()
    seqs = [0] * capture.wearer_count
    fused_count = 0
    for t, wearer in events:
        frame = capture.frame(wearer, float(t))
        seqs[wearer] += 1
        bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in frame.bodies)
        pose = frame.pose
        if space_from_world is not None:
            pose = pose_from_matrix(space_from_world[wearer] @ pose_matrix(pose))
        message = encode(Frame(seqs[wearer], int((T0 + t) * 1e9), bodies, None, pose))
        received = T0 + t + NETWORK_DELAY_S
        hub.handle_message(names[wearer].encode(), [message], received, received - T0)
        fused = hub.fuse_step(received)
        if fused is None:
            continue
        fused_count += 1
        truth = capture.truth(fused.t_s - T0)
        persons = [(p.person_id, p.joints) for p in fused.persons]
        if spaces is not None:
            persons = [(i, apply(spaces.gauge, joints)) for i, joints in persons]
        log.add(fused_count, persons, truth)
    summary = log.summary()
    errors = np.stack(log.errors) if log.errors else np.full((1, 25), np.nan)
    seen = errors[np.isfinite(errors)]
    return {
        "mpjpe_mm": summary["mpjpe_mm"],
        "median_mm": 1000.0 * float(np.median(seen)) if seen.size else float("nan"),
        "coverage": summary["coverage"],
        "erroneous": summary["erroneous"],
    }
