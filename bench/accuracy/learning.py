"""Learned-errors benchmark: does fusion, learning each sensor's error from the rig, beat the
hindsight oracle, and does what it learns rank the sensors as their true errors do?

Takes: each quick accuracy scenario (bench/accuracy/scenarios.py, the performers loop) run for
``--take-s`` seconds (30), under both simulator error models (Kinect v2, depth tracker), each
with every sensor at the model's defaults ("fixed") and with random per-sensor units
("random"), ``--runs`` seeds each; every take is fed to fusion with the defaults ("learned"),
the same with the sensor types' priors kept ("priors"), the plain tracking-state mean and
each sensor alone (report A's weights).

Tables (medians over seeds, targets marked ✓ / ✗):

1. fused MPJPE / hindsight oracle (bench/accuracy/oracle.py: per fused frame the best single
   view with its labels put right by the truth), overall and per joint group; target ≤ 0.90;
2. per take: learned fused trunk against the plain mean's (target ≤), legs against the best
   single sensor's over the take (target ≤ 1.2×), wrong labels (target ≤ 1 %);
3. Spearman rank correlation between each (sensor, group)'s learned error after the take and
   the true RMS error of that sensor's views for that group over the take's last 30 s, pooled
   over sensors × groups and per group across sensors (3 sensors or more), random units only
   (so that sensors differ); target ≥ 0.8;
4. re-learning: a ``--move-s`` take (60 s) of walking a circle in which sensor 2 turns 5° and
   shifts 10 cm half-way while fusion keeps its old pose: its learned error before and at the
   end, the time until it has come 90 % of the way (and until it is 0.9× the end value), the
   true error through the old pose (what there is to learn), and fused MPJPE per 5-s window,
   learned against priors (fixed units, ``--move-runs`` seeds).

Run: ``python -m bench learning`` (``--quick``: walking a circle only, one Kinect move take;
``--json FILE`` the raw results).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from typing import Literal

import numpy as np

from bench.accuracy.learning_runs import (
    LEARNED,
    ORACLE,
    PLAIN,
    PRIORS,
    TRUTH_WINDOW_S,
    Move,
    SensorMove,
    Take,
    run_move,
    run_take,
)
from bench.accuracy.scenarios import Scenario, scenarios
from skelfuse.agent.sim.sensor_units import ErrorModel
from skelfuse.fusion.rig_errors import GROUPS

COLUMNS = ("all", *GROUPS)
ORACLE_TARGET = 0.9
LEGS_TARGET = 1.2
WRONG_LABELS_TARGET = 0.01
SPEARMAN_TARGET = 0.8
MODELS: dict[str, ErrorModel] = {
    f"{kind}, {'random' if random else 'fixed'} units": ErrorModel(kind, random)
    for kind in ("kinect", "tracker")
    for random in (False, True)
}  # fmt: skip
"""Error model name → the simulator's error model."""
MOVE_SCENARIO = "walking a circle"
MOVE_BUMP = SensorMove(sensor=1, yaw_deg=5.0, shift_mm=100.0, at_s=30.0)


def take_scenarios(quick: bool, take_s: float) -> list[Scenario]:
    """The quick accuracy scenarios (``quick``: walking a circle only), each ``take_s`` long."""
    chosen = [s for s in scenarios(True) if not quick or s.name == MOVE_SCENARIO]
    return [replace(s, duration_s=max(take_s, s.duration_s)) for s in chosen]


def _mark(ok: bool) -> str:
    return "✓" if ok else "✗"


def _median(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else math.nan


def _by_case(takes: Sequence[Take]) -> dict[tuple[str, str], list[Take]]:
    out: dict[tuple[str, str], list[Take]] = {}
    for take in takes:
        out.setdefault((take.model, take.scenario), []).append(take)
    return out


def _med(takes: Sequence[Take], value: Callable[[Take], float]) -> float:
    return _median([value(t) for t in takes])


def print_oracle_table(takes: Sequence[Take]) -> None:
    """Table 1: fused / oracle MPJPE per group, learned and priors."""
    if not takes:
        return
    print(f"\n## Fused MPJPE / hindsight oracle (median over seeds; target ≤ {ORACLE_TARGET})\n")
    head = " / ".join(COLUMNS)
    print(f"| error model | scenario | oracle mm {head} | learned ÷ oracle | priors ÷ oracle |")
    print("|---|---|---|---|---|")
    for (model, scenario), group in _by_case(takes).items():
        oracle = [_median([t.mpjpe[ORACLE][c] for t in group]) for c in COLUMNS]
        cells = []
        for method in (LEARNED, PRIORS):
            ratios = [_median([t.mpjpe[method][c] / t.mpjpe[ORACLE][c] for t in group])
                      for c in COLUMNS]  # fmt: skip
            cells.append(" / ".join(f"{r:.2f}{_mark(r <= ORACLE_TARGET)}" for r in ratios))
        o = " / ".join(f"{v:.0f}" for v in oracle)
        print(f"| {model} | {scenario} | {o} | {cells[0]} | {cells[1]} |")


def _best_single_legs(take: Take) -> float:
    singles = [v["legs"] for k, v in take.mpjpe.items() if k.startswith("single ")]
    return min(singles) if singles else math.nan


def print_targets_table(takes: Sequence[Take]) -> None:
    """Table 2: trunk against the plain mean, legs against the best single view, labels."""
    if not takes:
        return
    print("\n## Learned fusion against the plain mean and the best single sensor (mm, median)\n")
    print(f"Targets: fused trunk ≤ plain mean's; fused legs ≤ {LEGS_TARGET}× the best single "
          f"sensor's over the take; wrong labels ≤ {WRONG_LABELS_TARGET:.0%}.\n")  # fmt: skip
    print("| error model | scenario | trunk: fused / plain mean | legs: fused / best single "
          "(ratio) | wrong labels |")  # fmt: skip
    print("|---|---|---|---|---|")
    for (model, scenario), group in _by_case(takes).items():
        trunk = _med(group, lambda t: t.mpjpe[LEARNED]["trunk"])
        plain = _med(group, lambda t: t.mpjpe[PLAIN]["trunk"])
        legs = _med(group, lambda t: t.mpjpe[LEARNED]["legs"])
        single = _med(group, _best_single_legs)
        ratio = _med(group, lambda t: t.mpjpe[LEARNED]["legs"] / _best_single_legs(t))
        wrong = _med(group, lambda t: t.wrong_labels)
        print(f"| {model} | {scenario} | {trunk:.0f} / {plain:.0f} {_mark(trunk <= plain)} | "
              f"{legs:.0f} / {single:.0f} ({ratio:.2f}) {_mark(ratio <= LEGS_TARGET)} | "
              f"{wrong:.2%} {_mark(wrong <= WRONG_LABELS_TARGET)} |")  # fmt: skip


def _rho(value: float) -> str:
    return "–" if not math.isfinite(value) else f"{value:.2f}{_mark(value >= SPEARMAN_TARGET)}"


def print_spearman_table(takes: Sequence[Take]) -> None:
    """Table 3: learned against true error, rank correlation (random units only)."""
    if not any(t.model.endswith("random units") for t in takes):
        return
    print(f"\n## Learned error against the views' true error: Spearman ρ after the take, over "
          f"its last {TRUTH_WINDOW_S:.0f} s (random units; median over seeds, range in "
          f"brackets; target ≥ {SPEARMAN_TARGET})\n")  # fmt: skip
    print("| error model | scenario | pooled over sensors × groups | "
          + " | ".join(f"{g} across sensors" for g in GROUPS) + " |")  # fmt: skip
    print("|---|---|---|" + "---|" * len(GROUPS))
    for (model, scenario), group in _by_case(takes).items():
        if not model.endswith("random units"):
            continue
        pooled = [t.spearman["pooled"] for t in group]
        span = f" ({min(pooled):.2f}–{max(pooled):.2f})" if all(map(math.isfinite, pooled)) else ""
        cells = [_rho(_median([t.spearman[g] for t in group])) for g in GROUPS]
        print(f"| {model} | {scenario} | {_rho(_median(pooled))}{span} | "
              + " | ".join(cells) + " |")  # fmt: skip
    for model in dict.fromkeys(t.model for t in takes if t.model.endswith("random units")):
        pooled = [t.spearman["pooled"] for t in takes if t.model == model]
        print(f"| {model} | every take | {_rho(_median(pooled))} |" + " |" * len(GROUPS))


def print_move_tables(moves: Sequence[Move], bump: SensorMove) -> None:
    """Table 4: the moved sensor's learned error, and fused MPJPE per window."""
    if not moves:
        return
    seeds = len({m.seed for m in moves})
    print(f"\n## Re-learning a moved sensor: {moves[0].moved} turns {bump.yaw_deg:g}° about "
          f"the vertical and shifts {bump.shift_mm:g} mm at {bump.at_s:g} s, fusion keeps its "
          f"old pose (fixed units; median over {seeds} seed(s))\n")  # fmt: skip
    print("| error model | group | learned before (mm) | learned at the end | true, old pose, "
          "at the end | true, true pose, before / end | 90 % of the way after | ≥ 0.9× end "
          "after |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for model in dict.fromkeys(m.model for m in moves):
        runs = [m for m in moves if m.model == model]
        for g in GROUPS:

            def med(field: str, g: str = g, runs: list[Move] = runs) -> float:
                return _median([getattr(m, field)[g] for m in runs])

            print(
                f"| {model} | {g} | {med('before'):.0f} | {med('steady'):.0f} | "
                f"{med('registered_after'):.0f} | {med('true_before'):.0f} / "
                f"{med('true_after'):.0f} | {med('rise_s'):.1f} s | {med('level_s'):.1f} s |"
            )
    print(f"\nFused MPJPE (mm, all joints) per window; the move is at {bump.at_s:g} s.\n")
    models = list(dict.fromkeys(m.model for m in moves))
    print("| window | " + " | ".join(f"{m}: learned / priors" for m in models) + " |")
    print("|---|" + "---|" * len(models))
    for index, row in enumerate(moves[0].windows):
        cells = []
        for model in models:
            runs = [m for m in moves if m.model == model and index < len(m.windows)]
            learned = _median([m.windows[index].get(LEARNED, math.nan) for m in runs])
            priors = _median([m.windows[index].get(PRIORS, math.nan) for m in runs])
            cells.append(f"{learned:.0f} / {priors:.0f}")
        start = row["start_s"]
        print(f"| {start:.0f}–{start + 5:.0f} s | " + " | ".join(cells) + " |")


def run_all(chosen: Sequence[Scenario], models: dict[str, ErrorModel], runs: int) -> list[Take]:
    """Every take: scenario × error model × seed (progress on stderr)."""
    takes: list[Take] = []
    if runs <= 0:
        return takes
    for label, model in models.items():
        for scenario in chosen:
            started = time.perf_counter()
            takes += [run_take(scenario, seed, model, label) for seed in range(runs)]
            print(f"  {label}, {scenario.name}: {time.perf_counter() - started:.0f} s",
                  file=sys.stderr)  # fmt: skip
    return takes


def run_moves(
    move_s: float, runs: int, bump: SensorMove = MOVE_BUMP,
    kinds: Sequence[Literal["kinect", "tracker"]] = ("kinect", "tracker"),
) -> list[Move]:  # fmt: skip
    """The move takes, each error model of ``kinds`` at fixed units, ``runs`` seeds each."""
    base = next(s for s in scenarios(True) if s.name == MOVE_SCENARIO)
    scenario = replace(base, duration_s=move_s)
    out = []
    for kind in kinds:
        label = f"{kind}, fixed units"
        out += [run_move(scenario, seed, ErrorModel(kind, False), label, bump)
                for seed in range(runs)]  # fmt: skip
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the command line, run the takes, print the tables; returns the exit status."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3, help="seeds per scenario and model (0: "
                        "the move takes only)")  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="walking a circle only")
    parser.add_argument("--take-s", type=float, default=30.0, help="seconds per take")
    parser.add_argument("--move-s", type=float, default=60.0, help="seconds of a move take")
    parser.add_argument("--move-runs", type=int, default=None, help="seeds per move model")
    parser.add_argument("--json", metavar="FILE", help="write the raw results here")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    takes = run_all(take_scenarios(args.quick, args.take_s), MODELS, args.runs)
    move_runs = args.move_runs if args.move_runs is not None else (1 if args.quick else 2)
    bump = replace(MOVE_BUMP, at_s=args.move_s / 2)
    kinds: tuple[Literal["kinect", "tracker"], ...] = (
        ("kinect",) if args.quick else ("kinect", "tracker")
    )
    moves = run_moves(args.move_s, move_runs, bump, kinds) if move_runs > 0 else []
    print_oracle_table(takes)
    print_targets_table(takes)
    print_spearman_table(takes)
    print_move_tables(moves, bump)
    print(f"\n{time.perf_counter() - started:.0f} s wall")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump({"takes": [asdict(t) for t in takes],
                       "moves": [asdict(m) for m in moves]}, out, indent=1)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
