"""Moving sensors (issue 15 item 5, report B): the figures of docs/benchmarks.md "Moving sensors".

    .venv/bin/python -m bench moving_sensors [--seeds 3] [--part a|b|all] [--fusion server|minimal]
        [--turn-speeds 1,5] [--pose-noise-mm 0] [--pose-noise-deg 0] [--spaces one|per-wearer]

(a) Report B's measure in simulation (:mod:`bench.moving.frames`): % of erroneous frames
    for head, hands and feet of a person filmed by a head-mounted sensor turning by report B's
    schedule, per rotation axis, with per-frame poses against the fixed-sensor assumption.
(b) The fused error of mutual capture (:mod:`bench.moving.fused`) as the
    pose-to-frame mismatch grows (0, 10, 20, 50 ms), at report B's turn rates (≤ 20°/s) and five
    times faster (≤ 100°/s). ``--fusion server`` feeds the production FusionHub
    (:mod:`bench.moving.hub`); ``minimal`` is the bench's own placement + weighted
    average, not the server's fusion. ``--spaces per-wearer`` (server fusion, 0 ms mismatch):
    each wearer's headset in its own tracking space (:mod:`bench.moving.spaces`), the
    spaces' transforms stored, or solved by a skeleton calibration run, against one shared space.

Each figure is the median over ``--seeds`` runs. Geometry only: the figures do not depend on the
machine's load (printed anyway, with the run time).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np

from bench.moving.frames import (
    CONDITIONS,
    WIDTHS_M,
    FrameCase,
    erroneous_frames,
    reduction_percent,
)
from bench.moving.fused import MISMATCHES_MS, FusedCase, minimal_errors
from skelfuse.agent.sim.head_mounted import AXES


def frames_table(seeds: int, walk_m: float, noisy: bool = True) -> list[str]:
    """Part (a) as markdown rows: per axis, each condition's erroneous % and report B's cut."""
    names = list(WIDTHS_M)
    lines = [
        "| axis | poses | " + " | ".join(names) + " |",
        "|---|---|" + "---:|" * len(names),
    ]
    for axis in AXES:
        runs = [
            erroneous_frames(FrameCase(axis, seed=s, walk_m=walk_m, noisy_sensor=noisy))
            for s in range(seeds)
        ]
        medians = {
            c: {n: float(np.median([r[c][n] for r in runs])) for n in names} for c in CONDITIONS
        }
        for condition in CONDITIONS:
            cells = []
            for n in names:
                missing = float(np.median([r[condition][f"{n} missing"] for r in runs]))
                note = f" ({missing:.0f} missing)" if missing > 0 else ""
                cells.append(f"{medians[condition][n]:.1f}{note}")
            lines.append(f"| {axis} | {condition} | " + " | ".join(cells) + " |")
        cut = [
            reduction_percent(medians[CONDITIONS[0]][n], medians[CONDITIONS[1]][n]) for n in names
        ]
        lines.append(
            f"| {axis} | cut | "
            + " | ".join("–" if np.isnan(c) else f"{c:.0f} %" for c in cut)
            + " |"
        )
    return lines


def fused_table(
    seeds: int,
    turn_speed: float,
    errors_of: Callable[[FusedCase], dict[str, float]],
    noise: tuple[float, float] = (0.0, 0.0),
) -> list[str]:
    """Part (b) as markdown rows: per axis, MPJPE / per-joint median (mm) for each mismatch."""
    lines = [
        "| axis | " + " | ".join(f"{m:.0f} ms" for m in MISMATCHES_MS) + " | coverage |",
        "|---|" + "---:|" * (len(MISMATCHES_MS) + 1),
    ]
    for axis in AXES:
        cells, coverage = [], []
        for mismatch in MISMATCHES_MS:
            runs = [
                errors_of(
                    FusedCase(
                        axis,
                        mismatch,
                        seed=s,
                        turn_speed=turn_speed,
                        position_noise_mm=noise[0],
                        rotation_noise_deg=noise[1],
                    )
                )
                for s in range(seeds)
            ]
            mpjpe = float(np.median([r["mpjpe_mm"] for r in runs]))
            median = float(np.median([r["median_mm"] for r in runs]))
            coverage.append(float(np.median([r["coverage"] for r in runs])))
            cells.append(f"{mpjpe:.1f} / {median:.1f}")
        lines.append(f"| {axis} | " + " | ".join(cells) + f" | {min(coverage):.2f} |")
    return lines


def spaces_table(seeds: int, turn_speed: float) -> list[str]:
    """``--spaces per-wearer`` as markdown rows: per axis, MPJPE / median (mm) at 0 ms with one
    shared space, each wearer's space stored, and solved by a calibration run; and the solved
    spaces' worst error against the truth (deg, mm), medians over seeds."""
    from bench.moving.hub import hub_errors
    from bench.moving.spaces import solved_spaces, stored_spaces

    lines = [
        "| axis | one space | per-wearer, stored | per-wearer, solved | solved error deg / mm |",
        "|---|---:|---:|---:|---:|",
    ]
    for axis in AXES:
        cases = [FusedCase(axis, 0.0, seed=s, turn_speed=turn_speed) for s in range(seeds)]
        solved = [solved_spaces(c) for c in cases]
        runs = {
            "one": [hub_errors(c) for c in cases],
            "stored": [hub_errors(c, stored_spaces(c.wearers)) for c in cases],
            "solved": [hub_errors(c, s) for c, s in zip(cases, solved, strict=True)],
        }
        cells = [
            f"{np.median([r['mpjpe_mm'] for r in rs]):.1f} / "
            f"{np.median([r['median_mm'] for r in rs]):.1f}"
            for rs in runs.values()
        ]
        worst_deg = np.median([max(d for d, _ in s.errors.values()) for s in solved])
        worst_mm = np.median([max(m for _, m in s.errors.values()) for s in solved])
        lines.append(f"| {axis} | " + " | ".join(cells) + f" | {worst_deg:.2f} / {worst_mm:.1f} |")
    return lines


def _fused_errors(fusion: str) -> Callable[[FusedCase], dict[str, float]]:
    if fusion == "minimal":
        return minimal_errors
    from bench.moving.hub import hub_errors

    return hub_errors


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="runs per figure (median)")
    parser.add_argument("--part", choices=["a", "b", "all"], default="all")
    parser.add_argument("--fusion", choices=["server", "minimal"], default="server")
    parser.add_argument(
        "--turn-speeds", default="1,5", help="(b): schedule rates, comma-separated (1: report B's)"
    )
    parser.add_argument("--pose-noise-mm", type=float, default=0.0, help="(b): σ per axis")
    parser.add_argument("--pose-noise-deg", type=float, default=0.0, help="(b): σ per axis")
    parser.add_argument(
        "--spaces",
        choices=["one", "per-wearer"],
        default="one",
        help="(b): per-wearer = each headset in its own tracking space, stored and solved",
    )
    args = parser.parse_args(argv)
    start = time.perf_counter()
    print(f"load average at start: {os.getloadavg()}")
    if args.part in ("a", "all"):
        for title, walk in (("standing (report B's test)", 0.0), ("both walking", 0.6)):
            print(f"\n(a) erroneous frames %, {title}, median of {args.seeds} seeds\n")
            print("\n".join(frames_table(args.seeds, walk)))
    if args.part in ("b", "all") and args.spaces == "per-wearer":
        for speed in (float(v) for v in args.turn_speeds.split(",")):
            print(
                f"\n(b) fused error, server fusion, 0 ms mismatch, MPJPE / median mm, schedule "
                f"x{speed:g} (<= {20 * speed:.0f} deg/s), median of {args.seeds} seeds\n"
            )
            print("\n".join(spaces_table(args.seeds, speed)))
    elif args.part in ("b", "all"):
        errors_of = _fused_errors(args.fusion)
        noise = (args.pose_noise_mm, args.pose_noise_deg)
        for speed in (float(v) for v in args.turn_speeds.split(",")):
            print(
                f"\n(b) fused error, {args.fusion} fusion, MPJPE / median mm, schedule x{speed:g} "
                f"(<= {20 * speed:.0f} deg/s), pose noise {noise[0]:g} mm / {noise[1]:g} deg, "
                f"median of {args.seeds} seeds\n"
            )
            print("\n".join(fused_table(args.seeds, speed, errors_of, noise)))
    print(f"\nload average at end: {os.getloadavg()}; {time.perf_counter() - start:.0f} s")
