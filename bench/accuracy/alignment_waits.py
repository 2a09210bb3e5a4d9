"""The alignment wait of the live rig's 10 sensors under each policy, in simulated time.

``python -m bench alignment_waits``: 10 sensors at 30 fps at random capture phases (one draw per
seed), each frame delivered 2 ms after capture plus an exponential delay (``--jitter-ms``, in
order per sensor), fed to :class:`fusion.alignment.Alignment` alone with the live loop's timer
(a step at every arrival and at every ``due_s``). Per policy: the wait (fusion time − instant)
p50 / p99, the share of instants with a sensor carried forward, and the mean horizon of those
carried. Pure logic on times, so the figures do not depend on the machine's load; what the live
server adds after the wait (fusion step, publishing, the socket) is in docs/benchmarks.md
"Load" (7.8 / 23.7 ms p50 / p99 on a quiet machine).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from skelfuse.fusion.alignment import Alignment, SensorTiming

PERIOD_S = 1 / 30
DELIVERY_S = 0.002
T0 = 1_800_000_000.0
POLICIES: dict[str, dict[str, object]] = {
    "aligned": {"policy": "aligned"},
    "phased": {"policy": "phased"},
    "deadline 10 ms (wait grid)": {"policy": "deadline", "deadline_s": 0.010},
    "deadline 5 ms, horizon grid, skip": {
        "policy": "deadline", "deadline_s": 0.005, "grid": "horizon", "skip_expected_late": True,
    },
    "deadline 10 ms, horizon grid, skip": {
        "policy": "deadline", "deadline_s": 0.010, "grid": "horizon", "skip_expected_late": True,
    },
    "deadline 15 ms, horizon grid, skip": {
        "policy": "deadline", "deadline_s": 0.015, "grid": "horizon", "skip_expected_late": True,
    },
}  # fmt: skip


def simulate(
    options: dict[str, object], sensors: int, seconds: float, jitter_ms: float, seed: int
) -> dict[str, float]:
    """One rig (``seed`` draws the phases and delays) under one policy; figures in ms / share."""
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0.0, PERIOD_S, sensors)
    base = math.floor(T0 / PERIOD_S) * PERIOD_S
    events = []
    for k, phase in enumerate(phases):
        last = 0.0
        for n in range(int(seconds / PERIOD_S)):
            capture = base + n * PERIOD_S + phase
            extra = rng.exponential(jitter_ms / 1000) if jitter_ms > 0 else 0.0
            last = max(capture + DELIVERY_S + extra, last)
            events.append((last, k, capture))
    events.sort()
    policy = Alignment(output_hz=30.0, **options)  # type: ignore[arg-type]
    newest: dict[int, float] = {}
    waits: list[float] = []
    horizons: list[float] = []
    carried = 0

    def step(now: float) -> None:
        nonlocal carried
        timings = [SensorTiming(str(k), t, PERIOD_S) for k, t in newest.items()]
        instant = policy.next_instant(timings, now)
        if instant is None or now < base + 3.0:  # after the phase is chosen
            return
        waits.append(now - instant.t_s)
        carried += bool(instant.late)
        horizons.extend(h for _, h in instant.late)

    for arrival, k, capture in events:
        while (due := policy.due_s) is not None and due <= arrival:
            step(due)
        newest[k] = capture
        step(arrival)
    ms = np.array(waits) * 1000
    return {
        "wait_p50_ms": float(np.percentile(ms, 50)),
        "wait_p99_ms": float(np.percentile(ms, 99)),
        "carried": carried / max(len(waits), 1),
        "horizon_ms": float(np.mean(horizons) * 1000) if horizons else 0.0,
        "sensors_carried": len(horizons) / max(len(waits), 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--sensors", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--jitter-ms", type=float, default=0.0)
    args = parser.parse_args(argv)
    print(
        f"\n{args.sensors} sensors × 30 fps at random phases, delivery 2 ms + exponential "
        f"{args.jitter_ms:g} ms, {args.seeds} rigs × {args.seconds:g} s (medians over rigs)\n"
    )
    print(
        "| policy | wait p50 ms | wait p99 ms | instants with a sensor carried "
        "| sensors carried per instant | mean horizon ms |"
    )
    print("|---|---:|---:|---:|---:|---:|")  # fmt: skip
    for label, options in POLICIES.items():
        rows = [
            simulate(options, args.sensors, args.seconds, args.jitter_ms, seed)
            for seed in range(args.seeds)
        ]
        med = {key: float(np.median([r[key] for r in rows])) for key in rows[0]}
        print(f"| {label} | {med['wait_p50_ms']:.1f} | {med['wait_p99_ms']:.1f} | "
              f"{med['carried']:.0%} | {med['sensors_carried']:.1f} | "
              f"{med['horizon_ms']:.1f} |")  # fmt: skip
    return 0
