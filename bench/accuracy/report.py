"""The accuracy benchmark's tables (Markdown, as in docs/benchmarks.md): filter latency, report
A's experiment, every method per scenario group, and the full method against the targets."""

from __future__ import annotations

import math

import numpy as np

from bench.accuracy.methods import BASELINE, BEST_SINGLE, FULL, METHODS

Metrics = dict[str, float]
"""One method's figures over one run (or one group), by ``Log.summary`` key."""

COLUMNS = ("mpjpe_mm", "p95_mm", "erroneous", "bone_cv", "bone_cv_settled", "jitter_mm",
           "id_switches", "duplicates", "coverage")  # fmt: skip


def group_row(metrics: list[Metrics]) -> Metrics:
    """One group's figure per metric: the median over its runs (id switches: the total)."""
    out: Metrics = {}
    for key in COLUMNS:
        values = [m[key] for m in metrics]
        finite = [v for v in values if math.isfinite(v)]
        if key == "id_switches":
            out[key] = float(np.sum(values))
        else:
            out[key] = float(np.median(finite)) if finite else math.nan
    return out


def _format(row: Metrics) -> str:
    """One table row's figures, in the order of the accuracy table's columns."""
    return (f"{row['mpjpe_mm']:.1f} | {row['p95_mm']:.0f} | {row['erroneous']:.1%} | "
            f"{row['bone_cv']:.1%} | {row['jitter_mm']:.1f} | {row['id_switches']:.0f} | "
            f"{row['duplicates']:.1%} | {row['coverage']:.0%}")  # fmt: skip


def print_filter_latency(latency: dict[str, Metrics]) -> None:
    """The ``filter_latency`` figures, one row per filter."""
    print("\nFilter latency at 30 Hz (per coordinate)\n")
    print("| filter | lag on a 1 m/s ramp | 90 % rise on a 10 cm step | noise left |")
    print("|---|---:|---:|---:|")
    for label, m in latency.items():
        print(f"| {label} | {m['ramp_lag_ms']:.0f} ms | {m['step_rise_90_ms']:.0f} ms "
              f"| {m['noise_ratio']:.0%} |")  # fmt: skip


def print_paper(paper: dict[str, Metrics]) -> None:
    """The ``paper_experiment`` figures, one row per (method, bone)."""
    print("\nReport A's experiment: 2 sensors, 50 fused frames of walking, bone lengths "
          "pre-measured standing 3 s in front of sensor 1\n")  # fmt: skip
    print("| method | bone | pre-measured mm | true mm | mean abs(fused − pre) mm | SD mm |")
    print("|---|---|---:|---:|---:|---:|")
    for key, m in paper.items():
        method, bone = key.split(" | ")
        print(f"| {method} | {bone} | {m['premeasured_mm']:.0f} | {m['true_mm']:.0f} "
              f"| {m['mean_abs_diff_mm']:.1f} | {m['sd_mm']:.1f} |")  # fmt: skip


def print_accuracy(
    results: dict[str, list[dict[str, Metrics]]],
    groups: dict[str, list[str]],
    runs_per_scenario: int,
    elapsed_s: float,
) -> dict[str, dict[str, Metrics]]:
    """Every method per scenario group, then the full method against the targets.

    Args:
        results: per scenario name, one ``run_once`` result per seed.
        groups: per report group, the names of its scenarios.
        runs_per_scenario: seeds per scenario (for the heading).
        elapsed_s: wall time of all runs (for the heading).

    Returns:
        Per group, per method (and the best single sensor), the group's figures.
    """
    print(f"\nAccuracy: {runs_per_scenario} seed(s) per scenario, {elapsed_s:.0f} s\n")
    print("| scenario | method | MPJPE mm | p95 mm | erroneous frames | bone CV | jitter mm "
          "| id switches | duplicates | coverage |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    summary: dict[str, dict[str, Metrics]] = {}
    verdicts: list[str] = []
    for group, names in groups.items():
        runs = [run for name in names for run in results[name]]
        singles = [label for label in runs[0] if label.startswith("single ")]
        best = [min((run[s] for s in singles), key=lambda m: m["mpjpe_mm"]) for run in runs]
        rows = {BEST_SINGLE: group_row(best)}
        for label in METHODS:
            rows[label] = group_row([run[label] for run in runs])
        summary[group] = rows
        for label, row in rows.items():
            print(f"| {group} | {label} | {_format(row)} |")
        full, base = rows[FULL], rows[BASELINE]
        beats = sum(
            run[FULL]["mpjpe_mm"] < b["mpjpe_mm"] for run, b in zip(runs, best, strict=True)
        )
        verdicts.append(
            f"| {group} | {1 - full['mpjpe_mm'] / base['mpjpe_mm']:.0%} | "
            f"{1 - full['erroneous'] / max(base['erroneous'], 1e-9):.0%} | "
            f"{full['mpjpe_mm'] / rows[BEST_SINGLE]['mpjpe_mm']:.2f}× ({beats}/{len(runs)}) | "
            f"{full['bone_cv']:.1%} ({full['bone_cv_settled']:.1%}) | "
            f"{full['id_switches']:.0f} |"
        )
    print("\nFull method against the targets\n")
    print("| scenario | MPJPE vs baseline (≥ 30 % lower) | erroneous frames vs baseline "
          "(≥ 50 % fewer) | MPJPE ÷ best single (runs better) | bone CV (< 2 %; after 2 s) "
          "| id switches (0) |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|")
    print("\n".join(verdicts))
    return summary


def print_labels(
    results: dict[str, list[dict[str, Metrics]]], groups: dict[str, list[str]]
) -> None:
    """Wrong labels per group for every method that labels views (targets: ≤ 1 % of the
    sensor × frame decisions, no person wrong for over 0.5 s once a front or side view sees
    them): the median over runs and the worst run."""
    print("\nMirror labels against the simulator's truth (median over runs; worst run)\n")
    print("| scenario | method | wrong-label rate (≤ 1 %) | longest wrong after a front or side "
          "view, s (≤ 0.5) |")  # fmt: skip
    print("|---|---|---:|---:|")
    for group, names in groups.items():
        runs = [run for name in names for run in results[name]]
        for label, settings in METHODS.items():
            if not settings.mirror.enabled:
                continue
            rates = [run[label]["wrong_labels"] for run in runs]
            longest = [run[label]["wrong_after_front_s"] for run in runs]
            finite = [r for r in rates if math.isfinite(r)]
            if not finite:
                continue
            print(
                f"| {group} | {label} | {np.median(finite):.2%} ({max(finite):.2%}) | "
                f"{np.nanmedian(longest):.2f} ({np.nanmax(longest):.2f}) |"
            )
