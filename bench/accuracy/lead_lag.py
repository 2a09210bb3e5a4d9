"""Lead / lag of the fused output, against the truth and against the views, per joint group.

Two measures of the same shift (positive: the output behind the motion; negative: ahead):

- **truth**: ``bench.accuracy.lag``'s best-fit shift against the simulator's performer;
- **views**: ``bench.accuracy.view_shift``'s best-fit shift against the sensors' own reported
  trajectories, each view at its capture time: no truth needed, so it also runs on a real
  recording. On the simulator both are printed side by side, with the views' own shift behind
  the truth (the views measure of the truth itself): where the measure holds, truth ≈ views +
  that row. It is not zero: the one-way network delay (2 ms) reads as a clock offset, and the
  simulated sensors' errors that follow the pose (a facing bias turning with the person) read
  as a shift.

Scenarios: the simulator's CMU walks and the walking circle (``bench/accuracy/scenarios.py``;
the same rig, wire bytes and production ``FusionHub`` in simulated time as the accuracy
benchmark), and the real four-camera clip fused through the ``mono`` source's bodies
(``bench/mono/clip_shift.py``: four ``rgb`` views of a real person, as recorded and with half
the cameras staggered by half a period), views only. Settings: the defaults, ``filter = "none"``,
the other alignment policies and late predictors (``--methods``).

Run: ``python -m bench lead_lag`` (``--runs N`` seeds per simulated scenario, medians;
``--quick`` one walk, one seed; ``--no-clip`` / ``--no-sim`` for one half; ``--sensor clean``
a simulated sensor whose errors do not follow the pose, to check the views measure).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from bench.accuracy.lag import best_shift, shift_errors
from bench.accuracy.runner import T0, SimulatedRig, _new_hub, feed
from bench.accuracy.scenarios import Scenario, scenarios
from bench.accuracy.view_shift import Take, shift_against_views, steady
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.fusion.rig_errors import GROUPS
from skelfuse.fusion.settings import AlignmentSettings, SmoothingSettings
from skelfuse.server.settings import FusionSettings

FloatArray = npt.NDArray[np.float64]
DEFAULT = FusionSettings()


def _with(
    alignment: AlignmentSettings | None = None, smoothing: SmoothingSettings | None = None
) -> FusionSettings:
    return replace(DEFAULT, alignment=alignment or DEFAULT.alignment,
                   smoothing=smoothing or DEFAULT.smoothing)  # fmt: skip


NO_FILTER = SmoothingSettings(filter="none")
METHODS: dict[str, FusionSettings] = {
    "default": DEFAULT,
    "filter none": _with(smoothing=NO_FILTER),
    "aligned": _with(alignment=AlignmentSettings(policy="aligned")),
    "aligned, filter none": _with(AlignmentSettings(policy="aligned"), NO_FILTER),
    "deadline, track": _with(alignment=replace(DEFAULT.alignment, predictor="track")),
    "deadline, own": _with(alignment=replace(DEFAULT.alignment, predictor="own")),
    "filter lead 0": _with(smoothing=replace(DEFAULT.smoothing, kalman_ca_predict_s=0.0)),
    "filter jerk 10": _with(smoothing=replace(DEFAULT.smoothing, kalman_ca_jerk_std=10.0)),
}
"""Every method the benchmark can run (``--methods`` picks some)."""
CLEAN_SENSOR = KinectV2Params(
    facing_bias=0.0, bias_trunk_m=0.004, bias_limb_m=0.006, bias_extremity_m=0.01,
    glitch_rate_hz=0.0, jitter_base_m=0.001, inferred_error_m=0.03,
)  # fmt: skip
"""``--sensor clean``: a simulated sensor without the facing bias (errors that turn with the
person), with a third of the Kinect v2's slow bias and no glitches: where the views measure and
the truth's should differ by the clock's one-way delay alone."""
SENSORS = {"kinect_v2": KinectV2Params(), "clean": CLEAN_SENSOR}
SIM_SCENARIOS = ("CMU 131_01 start-walk-stop, heading 0°", "CMU 131_01 start-walk-stop, "
                 "heading 120°", "CMU 02_01 walk, heading 60°", "walking a circle")  # fmt: skip


def truth_shifts(take: Take, scenario_truth: SimulatedRig) -> dict[str, float]:
    """Per joint group, the best-fit shift (ms) of the take's fused joints behind the truth
    (``bench.accuracy.lag.shift_errors``, person 0 of the performer); and ``mpjpe_mm``,
    ``jitter_mm`` (the error's second difference, as the accuracy benchmark's)."""
    performer = scenario_truth.performer
    kept = steady(take, np.asarray(take.fused_t))
    times = np.asarray(take.fused_t)[kept] - T0
    fused = np.stack(take.fused)[kept]
    cache: dict[float, FloatArray] = {}

    def truth_at(t: float) -> FloatArray:
        key = round(t, 9)
        if key not in cache:
            cache[key] = performer.joints_at(t)[0]
        return cache[key]

    out: dict[str, float] = {}
    for group, joints in GROUPS.items():
        chosen = list(joints)

        def truth_of(t: float, c: list[int] = chosen) -> FloatArray:
            return truth_at(t)[c]

        errors = shift_errors(times, fused[:, chosen], truth_of)
        out[group] = best_shift(errors) * 1000
    truth = np.stack([truth_at(float(t)) for t in times])
    error = fused - truth
    out["mpjpe_mm"] = float(np.nanmean(np.linalg.norm(error, axis=-1))) * 1000
    # As the accuracy benchmark's jitter: the error's second difference over consecutive steps.
    second = np.linalg.norm(error[:-2] - 2 * error[1:-1] + error[2:], axis=-1)
    out["jitter_mm"] = float(np.nanmean(second)) * 1000
    return out


VIEWS_ROW = "the views themselves, behind the truth"
"""The row of the views' own shift: truth ≈ views + this row, where the measure holds."""


def views_behind_truth(take: Take, rig: SimulatedRig) -> dict[str, float]:
    """Per joint group, how far (ms) the views are behind the truth: the views measure of a
    "fused" output that is the truth itself at the take's instants, sign turned (the views'
    errors that follow the motion, and the clock's one-way delay, read as such a shift)."""
    truth = [rig.performer.joints_at(t - T0)[0] for t in take.fused_t]
    exact = replace(take, fused=truth)
    return {g: -v for g, v in shift_against_views(exact).items()}


def sim_takes(scenario: Scenario, seed: int, methods: dict[str, FusionSettings],
              sensor: KinectV2Params = SENSORS["kinect_v2"]
              ) -> tuple[SimulatedRig, dict[str, Take]]:  # fmt: skip
    """One simulated capture seen by every method: each hub's fused frames and views."""
    rig = SimulatedRig(scenario, seed, sensor)
    hubs = {label: _new_hub(fusion, rig.names, rig.poses) for label, fusion in methods.items()}
    takes = {label: Take() for label in hubs}
    for capture in rig.captures():
        for label, hub in hubs.items():
            fused = feed(hub, capture)
            newest = hub.sensors[capture.name].frames[-1]
            if newest.frame.seq == capture.seq:
                takes[label].add_view(capture.name, newest.t_server_s, newest.frame,
                                      rig.poses[capture.sensor])  # fmt: skip
            if fused is not None:
                takes[label].add_fused(fused)
    return rig, takes


def sim_rows(chosen: list[Scenario], runs: int, methods: dict[str, FusionSettings],
             sensor: KinectV2Params = SENSORS["kinect_v2"]
             ) -> dict[str, dict[str, dict[str, float]]]:  # fmt: skip
    """Per scenario, per method: medians over ``runs`` seeds of the truth and views shifts."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for scenario in chosen:
        started = time.perf_counter()
        per_run: list[dict[str, dict[str, float]]] = []
        for seed in range(runs):
            rig, takes = sim_takes(scenario, seed, methods, sensor)
            per_run.append({})
            for label, take in takes.items():
                truth = truth_shifts(take, rig)
                views = shift_against_views(take)
                row = {f"truth_{g}": v for g, v in truth.items()}
                row |= {f"views_{g}": v for g, v in views.items()}
                per_run[-1][label] = row
            first = next(iter(takes.values()))
            per_run[-1][VIEWS_ROW] = {
                f"truth_{g}": v for g, v in views_behind_truth(first, rig).items()
            }
            per_run[-1][VIEWS_ROW] |= {f"views_{g}": math.nan for g in GROUPS} | {
                "truth_mpjpe_mm": math.nan,
                "truth_jitter_mm": math.nan,
            }
        out[scenario.name] = {
            label: {k: statistics.median(r[label][k] for r in per_run) for k in per_run[0][label]}
            for label in [*methods, VIEWS_ROW]
        }
        print(f"  {scenario.name}: {time.perf_counter() - started:.0f} s", file=sys.stderr)
    return out


def clip_rows(methods: dict[str, FusionSettings]) -> dict[str, dict[str, dict[str, float]]]:
    """The real clip, per timing, per method: the views shifts."""
    from bench.mono.clip_shift import TIMINGS, clip_take  # the clip's fixture and calibration

    out: dict[str, dict[str, dict[str, float]]] = {}
    for timing in TIMINGS:
        rows: dict[str, dict[str, float]] = {}
        for label, fusion in methods.items():
            shifts = shift_against_views(clip_take(fusion, timing))
            rows[label] = {f"views_{g}": v for g, v in shifts.items()}
        out[f"real clip, 4 rgb views, {timing}"] = rows
    return out


def print_table(name: str, rows: dict[str, dict[str, float]], note: str) -> None:
    """One scenario's table: per method, truth / views shift per group (ms), MPJPE (mm)."""
    truth = "truth_trunk" in next(iter(rows.values()))
    print(f"\n**{name}** ({note})\n")
    head = " | ".join(f"{g} truth / views (ms)" if truth else f"{g} views (ms)" for g in GROUPS)
    print(f"| method | {head} |" + (" MPJPE (mm) | jitter (mm) |" if truth else ""))
    print("|---|" + "---:|" * (len(GROUPS) + 2 * truth))
    for label, row in rows.items():

        def cell(g: str, r: dict[str, float] = row) -> str:
            views = f"{r[f'views_{g}']:.1f}".replace("nan", "–")
            return f"{r[f'truth_{g}']:.1f} / {views}" if truth else views

        tail = f" {row['truth_mpjpe_mm']:.1f} | {row['truth_jitter_mm']:.1f} |" if truth else ""
        tail = tail.replace("nan", "–")
        print(f"| {label} | " + " | ".join(cell(g) for g in GROUPS) + " |" + tail)


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the command line, run the scenarios, print the tables; returns the exit status."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=2, help="noise seeds per simulated scenario")
    parser.add_argument("--quick", action="store_true", help="one walk, one seed")
    parser.add_argument("--no-clip", action="store_true", help="the simulator only")
    parser.add_argument("--no-sim", action="store_true", help="the real clip only")
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=list(METHODS))
    parser.add_argument(
        "--sensor",
        choices=list(SENSORS),
        default="kinect_v2",
        help="the simulated sensor model (clean: errors that do not follow the pose)",
    )
    args = parser.parse_args(argv)
    runs = 1 if args.quick else args.runs
    methods = {label: METHODS[label] for label in args.methods}
    started = time.perf_counter()
    if not args.no_sim:
        wanted = SIM_SCENARIOS[:1] if args.quick else SIM_SCENARIOS
        chosen = [s for s in scenarios(quick=False) if s.name in wanted]
        for name, rows in sim_rows(chosen, runs, methods, SENSORS[args.sensor]).items():
            print_table(name, rows, f"median of {runs} runs")
    if not args.no_clip:
        for name, rows in clip_rows(methods).items():
            print_table(name, rows, "views only: no truth")
    print(f"\n{time.perf_counter() - started:.0f} s wall")
    return 0
