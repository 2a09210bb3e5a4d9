"""Lag of the fused output against the truth: the best-fit time shift, per joint group.

Lag is the time shift ``τ`` that best explains the fused trajectory as the truth delayed:
the ``τ`` minimising the mean squared distance between each fused joint at ``t_k`` and the true
joint at ``t_k − τ``, after removing each joint coordinate's constant offset over the take (a
sensor's bias or a side view's lean is an error, not a delay). The truth is the simulator's own
performer, evaluated at any instant, so the shift needs no resampling of the fused output;
shifts are tried on a 2 ms grid and refined to sub-millisecond resolution by a parabola through
the best three. Positive: the output is behind the motion.

The fused frames come from the accuracy benchmark's machinery (the same scenarios, sensors,
wire bytes and production ``FusionHub`` per method, in simulated time; persons matched to the
truth by ``metrics.Log``), so MPJPE and jitter are the accuracy benchmark's own.
Interpolation and clock alignment are exact in time (the ``none`` row measures what the
pipeline adds without a filter), so the lag is mostly the temporal filter's.

Run: ``python -m bench lag`` (``--runs N`` seeds per scenario, medians over runs; ``--quick``
two scenarios, one seed).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from bench.accuracy.metrics import Log
from bench.accuracy.runner import T0, SimulatedRig, _new_hub, feed
from bench.accuracy.scenarios import Scenario, scenarios
from bench.accuracy.sensor_flags import add_error_model_flags, error_model_from
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.sensor_units import DEFAULT_ERROR_MODEL, ErrorModel
from skelfuse.fusion.rig_errors import GROUPS
from skelfuse.fusion.settings import SmoothingSettings
from skelfuse.server.settings import FusionSettings

FloatArray = npt.NDArray[np.float64]
SHIFTS_S = np.arange(-0.060, 0.0601, 0.002)
"""Shifts tried (s); the fit is refined between grid points."""

METHODS: dict[str, FusionSettings] = {
    "none": FusionSettings(smoothing=SmoothingSettings(filter="none")),
    "One Euro (the default before)": FusionSettings(smoothing=SmoothingSettings(filter="one_euro")),
    "Kalman CV": FusionSettings(smoothing=SmoothingSettings(filter="kalman")),
    "Kalman CV + 33 ms prediction": FusionSettings(
        smoothing=SmoothingSettings(filter="kalman", kalman_predict_s=1 / 30)
    ),
    "Kalman CV + 12 ms lead, accel 5 (proposed)": FusionSettings(
        smoothing=SmoothingSettings(filter="kalman", kalman_accel_std=5.0, kalman_predict_s=0.012)
    ),
    "Kalman CA, damped, speed-adaptive, 6 ms lead (default)": FusionSettings(),
}
SCENARIO_NAMES = ("CMU 131_01 start-walk-stop, heading 0°", "walking a circle", "arm raises",
                  "squats")  # fmt: skip


def shift_errors(
    times: FloatArray, fused: FloatArray, truth_at: Callable[[float], FloatArray]
) -> FloatArray:
    """Mean squared distance (m²) between ``fused`` and the truth shifted by each of ``SHIFTS_S``.

    Args:
        times: (N,) instants of the fused samples, seconds.
        fused: (N, J, 3) fused joints at ``times``, metres, NaN where not reported.
        truth_at: the true (J, 3) joints at an instant.

    Returns:
        (len(SHIFTS_S),) the error of each shift, each joint coordinate's mean offset removed.
    """
    out = np.empty(len(SHIFTS_S))
    for s, shift in enumerate(SHIFTS_S):
        truth = np.stack([truth_at(float(t - shift)) for t in times])
        diff = fused - truth
        with np.errstate(invalid="ignore"):
            offset = np.nanmean(diff, axis=0, keepdims=True) if np.isfinite(diff).any() else 0.0
        centred = diff - offset
        out[s] = float(np.nanmean(np.sum(centred**2, axis=-1))) if np.isfinite(diff).any() else 0.0
    return out


def best_shift(errors: FloatArray) -> float:
    """The shift (s) at the minimum of ``errors`` (one per ``SHIFTS_S``), refined by a parabola
    through the best grid point and its neighbours; NaN when every error is NaN."""
    if not np.isfinite(errors).any():
        return math.nan
    i = int(np.nanargmin(errors))
    step = float(SHIFTS_S[1] - SHIFTS_S[0])
    if 0 < i < len(errors) - 1:
        a, b, c = errors[i - 1], errors[i], errors[i + 1]
        curvature = a - 2 * b + c
        if curvature > 0:
            return float(SHIFTS_S[i] + 0.5 * step * (a - c) / curvature)
    return float(SHIFTS_S[i])


def run_lag(
    scenario: Scenario,
    seed: int,
    methods: dict[str, FusionSettings],
    error_model: ErrorModel = DEFAULT_ERROR_MODEL,
) -> dict[str, dict[str, float]]:
    """One simulated capture seen by every method (as ``runner.run_once``, without the
    single-sensor hubs); per method: lag per joint group (ms), MPJPE and jitter (mm)."""
    rig = SimulatedRig(scenario, seed, KinectV2Params(), error_model)
    hubs = {label: _new_hub(fusion, rig.names, rig.poses) for label, fusion in methods.items()}
    logs = {label: Log() for label in hubs}
    instants: dict[str, list[float]] = {label: [] for label in hubs}  # simulated s per frame
    for capture in rig.captures():
        for label, hub in hubs.items():
            fused = feed(hub, capture)
            if fused is None:
                continue
            instants[label].append(fused.t_s - T0)
            persons = [(p.person_id, p.joints) for p in fused.persons]
            logs[label].add(len(instants[label]), persons, rig.performer.joints_at(fused.t_s - T0))
    cache: dict[float, FloatArray] = {}

    def truth_at(t: float) -> FloatArray:
        key = round(t, 9)
        if key not in cache:
            cache[key] = scenario.performer.joints_at(t)
        return cache[key]

    out: dict[str, dict[str, float]] = {}
    for label, log in logs.items():
        summary = log.summary()
        row = {"mpjpe_mm": summary["mpjpe_mm"], "jitter_mm": summary["jitter_mm"]}
        for group, joints in GROUPS.items():
            total = np.zeros(len(SHIFTS_S))
            for person, vectors in log.error_vectors.items():
                kept = [(i, d) for i, d in vectors if d is not None]
                if len(kept) < 10:
                    continue
                times = np.array([instants[label][i - 1] for i, _ in kept])
                fused = np.stack([d for _, d in kept]) + np.stack(
                    [truth_at(t)[person] for t in times]
                )

                def truth_of(t: float, p: int = person, j: tuple[int, ...] = joints) -> FloatArray:
                    return np.asarray(truth_at(t)[p][list(j)], dtype=np.float64)

                total += shift_errors(times, fused[:, joints], truth_of) * len(kept)
            row[f"lag_{group}_ms"] = best_shift(total) * 1000
        out[label] = row
    return out


def print_table(results: dict[str, list[dict[str, dict[str, float]]]], runs: int) -> None:
    """Per scenario, per method: medians over runs of lag per group, MPJPE and jitter."""
    keys = ("lag_trunk_ms", "lag_arms_ms", "lag_legs_ms", "mpjpe_mm", "jitter_mm")
    for name, per_run in results.items():
        print(f"\n**{name}** (median of {runs} runs)\n")
        print(
            "| filter | lag trunk (ms) | lag arms (ms) | lag legs (ms) | MPJPE (mm) | jitter (mm) |"
        )
        print("|---|---:|---:|---:|---:|---:|")
        for label in per_run[0]:
            cells = [statistics.median(r[label][k] for r in per_run) for k in keys]
            print(f"| {label} | " + " | ".join(f"{c:.1f}" for c in cells) + " |")


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the command line, run the scenarios, print the tables; returns the exit status."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3, help="noise seeds per scenario")
    parser.add_argument("--quick", action="store_true", help="two scenarios, one seed")
    add_error_model_flags(parser)
    args = parser.parse_args(argv)
    error_model = error_model_from(args)
    runs = 1 if args.quick else args.runs
    wanted = SCENARIO_NAMES[1:3] if args.quick else SCENARIO_NAMES
    chosen = [s for s in scenarios(quick=False) if s.name in wanted]
    results: dict[str, list[dict[str, dict[str, float]]]] = {}
    started = time.perf_counter()
    for scenario in chosen:
        t = time.perf_counter()
        results[scenario.name] = [
            run_lag(scenario, seed, METHODS, error_model) for seed in range(runs)
        ]
        print(f"  {scenario.name}: {time.perf_counter() - t:.0f} s", file=sys.stderr)
    print_table(results, runs)
    print(f"\n{time.perf_counter() - started:.0f} s wall")
    return 0
