"""Mutual capture fused by the production :class:`~skelfuse.fusion.hub.FusionHub` (the server's
moving-sensor support): part (b) of bench/moving_sensors.py with ``--fusion server``.

Each wearer's sensor registers as moving in the tracking space ``room`` with the identity as
the space's world transform (a ``sim_truth`` hint) and starts at a random phase of its 30 fps
clock; its frames go to the hub as wire bytes (bodies in the sensor frame, the headset's pose
attached) 2 ms after capture, the hub fusing on its default settings and output grid as the
live loop does. Fused persons are matched to the truth as the accuracy benchmark does
(:class:`bench.accuracy_metrics.Log`: trunk distance, Hungarian, 1 m gate).
"""

from __future__ import annotations

import numpy as np

from bench.accuracy_metrics import Log
from bench.moving_sensors_fused import FPS, FusedCase
from skelfuse.fusion.hub import FusionHub
from skelfuse.fusion.settings import HubSettings
from skelfuse.protocol.wire import Body, Frame, Hello, encode

T0 = 1_800_000_000.0
NETWORK_DELAY_S = 0.002


def _names(count: int) -> list[str]:
    return [f"head-{i}" for i in range(count)]


def new_hub(count: int, settings: HubSettings | None = None) -> FusionHub:
    """A hub with ``count`` moving sensors ``head-i`` registered in the space ``room``."""
    hub = FusionHub(settings or HubSettings())
    for name in _names(count):
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


def hub_errors(case: FusedCase) -> dict[str, float]:
    """MPJPE, per-joint median (mm), coverage and erroneous share of the hub's fused persons."""
    capture = case.capture()
    rng = np.random.default_rng(case.seed + 77)
    names = _names(capture.wearer_count)
    events = sorted(
        (phase + n / FPS, w)
        for w, phase in enumerate(rng.uniform(0.0, 1.0 / FPS, size=capture.wearer_count))
        for n in range(round(case.duration_s * FPS))
    )
    hub = new_hub(capture.wearer_count)
    log = Log()
    seqs = [0] * capture.wearer_count
    fused_count = 0
    for t, wearer in events:
        frame = capture.frame(wearer, float(t))
        seqs[wearer] += 1
        bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in frame.bodies)
        message = encode(Frame(seqs[wearer], int((T0 + t) * 1e9), bodies, None, frame.pose))
        received = T0 + t + NETWORK_DELAY_S
        hub.handle_message(names[wearer].encode(), [message], received, received - T0)
        fused = hub.fuse_step(received)
        if fused is None:
            continue
        fused_count += 1
        truth = capture.truth(fused.t_s - T0)
        log.add(fused_count, [(p.person_id, p.joints) for p in fused.persons], truth)
    summary = log.summary()
    errors = np.stack(log.errors) if log.errors else np.full((1, 25), np.nan)
    seen = errors[np.isfinite(errors)]
    return {
        "mpjpe_mm": summary["mpjpe_mm"],
        "median_mm": 1000.0 * float(np.median(seen)) if seen.size else float("nan"),
        "coverage": summary["coverage"],
        "erroneous": summary["erroneous"],
    }
