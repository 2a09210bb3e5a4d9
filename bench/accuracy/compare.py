"""Accuracy benchmark: every fusion method side by side against simulated ground truth.

Simulated Kinect v2 sensors (2–4, on a 3 m circle, 1 m high, looking at the middle) watch 1–3
people: CMU mocap walks (``../shared/data/cmu-mocap``, when present) and procedural scenarios
(walking a circle, turning on the spot, arm raises, squats, two people crossing, one person
walking in front of others). Each scenario run feeds the *same* sensor frames to one production
:class:`server.hub.FusionHub` per method, in simulated time: frames are encoded to wire bytes and
go through clock offsets, interpolation, tracking and fusion exactly as on the live server.

Methods (``FusionSettings`` variants, one run):
- single sensor k: a hub that receives only sensor k's frames (report A's weights; a single
  view fuses to itself). "best single sensor" is the best of them *per run*, chosen in
  hindsight by MPJPE: an oracle no live system has;
- plain mean: Inferred and Tracked joints weigh the same;
- tracking-state weights: report A's baseline (NotTracked 0, Inferred 0.3, Tracked 0.7);
- + bone length (online reference lengths, chain propagation), + range of motion, + facing,
  + mirrored-view correction: each adds one term to the previous row;
- full: + the damped-acceleration Kalman filter (``kalman_ca``) and reference bone lengths on
  the output (the default settings); the same with One Euro (the default before) and with the
  constant-velocity Kalman filter.

Metrics per method, over every fused frame and every true person (persons matched to the truth
by the Hungarian algorithm on trunk distance, gated at 1 m):
- MPJPE and p95 (mm) over the joints reported; coverage = share of (frame, person, joint) reported;
- erroneous frames (report B's criterion): share of (frame, person) where the head, a hand or an
  ankle is more than 10 cm off or missing;
- bone CV: coefficient of variation of each of the 24 bone lengths over the run, mean over bones;
  also "settled", leaving out each person's first 2 s (while the online reference settles);
- jitter (mm): mean norm of the second difference of the error over consecutive fused frames;
- id switches: times a true person's matched id changes; duplicates: share of frames with more
  published persons than people in the room.

Run: ``python -m bench accuracy`` (``--runs N`` seeds per scenario, ``--quick`` for a short
subset, ``--json FILE`` raw results, ``--paper`` report A's own experiment only,
``--latency`` the filters' added latency only, ``--birth`` the birth-labelling scenarios only,
``--no-mirror-redecide`` with ``FusionSettings.mirror.redecide`` off, as before,
``--no-mirror-turns`` with ``mirror.unbiased_facing`` off and ``mirror.redecide_views = 1``,
as before they became the defaults; ``--alignment`` the alignment policies side by side only:
MPJPE against ``aligned`` and the alignment wait (aligned, phased, deadline 5/10/20 ms),
``--jitter-ms`` adding delivery jitter; ``--error-model tracker`` the depth body tracker's
error model in place of the Kinect v2 model fusion was tuned on, ``--random-sensors`` every
sensor a unit with random parameters: docs/simulator.md).

Labels: the wrong-label rate (share of sensor × frame labelling decisions that disagree with the
simulator's truth: ``FusedPerson.mirrored`` against ``Observation.mirrored``) and the longest
time a person stays wrong once a front or side view sees them (``print_labels``).

The parts: ``scenarios`` (who moves, seen by how many sensors), ``methods``
(the settings compared), ``runner`` (one capture through every method),
``metrics`` (the figures), ``paper`` (report A's experiment),
``filter_latency`` and ``report`` (the tables).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

from bench.accuracy.alignment import chosen_policies, print_alignment, run_alignment
from bench.accuracy.filter_latency import filter_latency
from bench.accuracy.methods import METHODS
from bench.accuracy.oracle import print_oracle, run_oracle
from bench.accuracy.paper import paper_experiment
from bench.accuracy.report import (
    print_accuracy,
    print_filter_latency,
    print_labels,
    print_paper,
)
from bench.accuracy.runner import run_once
from bench.accuracy.scenarios import CMU_DIR, birth_scenarios, scenarios
from bench.accuracy.sensor_flags import add_error_model_flags, error_model_from
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.sensor_units import DEFAULT_ERROR_MODEL, ErrorModel
from skelfuse.fusion.settings import FusionSettings


def main(argv: list[str] | None = None) -> int:
    """Parse the command line, run what it asks for, print the tables; returns the exit status."""
    args = _parser().parse_args(argv)
    methods = _methods(args)
    error_model = error_model_from(args)
    if args.oracle:
        oracle = {
            sc.name: [
                run_oracle(sc, seed, KinectV2Params(), error_model=error_model)
                for seed in range(args.runs)
            ]
            for sc in scenarios(args.quick)
        }
        print_oracle(oracle)
        return 0
    if args.alignment:
        return alignment_only(
            args.quick,
            args.runs,
            args.jitter_ms,
            args.json,
            chosen_policies(args.policies),
            error_model,
        )

    if not args.paper and not args.birth:
        print_filter_latency(filter_latency())
    if args.latency:
        return 0
    paper = {} if args.birth else paper_experiment()
    if not args.birth:
        print_paper(paper)
    if args.paper:
        return 0

    if not (CMU_DIR / "scaled_131_01.bvh").is_file():
        print(f"\nnote: CMU data not found at {CMU_DIR}; procedural scenarios only")
    started = time.perf_counter()
    results, groups = _run_scenarios(args.birth, args.quick, args.runs, methods, error_model)
    elapsed = time.perf_counter() - started

    summary = print_accuracy(results, groups, args.runs, elapsed)
    print_labels(results, groups)
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "runs": results, "paper": paper},
                                        indent=1))  # fmt: skip
    return 0


def _parser() -> argparse.ArgumentParser:
    """The command line: runs and subsets, the variants of every method, the alignment table."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=1, help="noise seeds per scenario")
    parser.add_argument("--quick", action="store_true", help="a short subset of scenarios")
    parser.add_argument("--json", type=Path, default=None, help="write raw results here")
    parser.add_argument("--paper", action="store_true", help="only report A's experiment")
    parser.add_argument("--latency", action="store_true", help="only the filters' latency")
    parser.add_argument(
        "--birth",
        action="store_true",
        help="only the birth-labelling scenarios (seen from behind first, ...)",
    )
    parser.add_argument("--no-mirror-redecide", action="store_true",
                        help="no method re-decides labels from all views' anatomy "
                             "(mirror_redecide off, as before issue 10)")  # fmt: skip
    parser.add_argument("--oracle", action="store_true",
                        help="only fused vs the hindsight oracle (accuracy/oracle.py)")  # fmt: skip
    parser.add_argument("--no-mirror-turns", action="store_true",
                        help="every method with mirror_unbiased_facing off and "
                             "mirror_redecide_views = 1 (the defaults before)")  # fmt: skip
    parser.add_argument("--alignment", action="store_true",
                        help="only the alignment policies side by side "
                             "(bench/accuracy/alignment.py)")  # fmt: skip
    parser.add_argument("--jitter-ms", type=float, default=0.0,
                        help="--alignment: mean exponential delivery jitter, ms")  # fmt: skip
    parser.add_argument("--policies", default=None,
                        help="--alignment: comma-separated policy labels "
                             "(bench/accuracy/alignment.py ALL_POLICIES)")  # fmt: skip
    add_error_model_flags(parser)
    return parser


def _methods(args: argparse.Namespace) -> dict[str, FusionSettings]:
    """The methods compared, with the command line's variants applied to each."""
    methods = METHODS
    if args.no_mirror_redecide:
        methods = {
            label: replace(m, mirror=replace(m.mirror, redecide=False))
            for label, m in METHODS.items()
        }
    if args.no_mirror_turns:
        methods = {
            label: replace(m, mirror=replace(m.mirror, unbiased_facing=False, redecide_views=1))
            for label, m in methods.items()
        }
    return methods


def _run_scenarios(
    birth: bool,
    quick: bool,
    runs: int,
    methods: dict[str, FusionSettings],
    error_model: ErrorModel = DEFAULT_ERROR_MODEL,
) -> tuple[dict[str, list[dict[str, dict[str, float]]]], dict[str, list[str]]]:
    """Every scenario (the birth ones with ``birth``) with ``runs`` noise seeds: per scenario,
    each seed's figures by method; and the scenarios' names by group."""
    params = KinectV2Params()
    results: dict[str, list[dict[str, dict[str, float]]]] = {}
    groups: dict[str, list[str]] = {}
    for scenario in birth_scenarios(quick) if birth else scenarios(quick):
        groups.setdefault(scenario.group, []).append(scenario.name)
        t = time.perf_counter()
        results[scenario.name] = [
            run_once(scenario, seed, params, methods, error_model=error_model)
            for seed in range(runs)
        ]
        print(f"  {scenario.name}: {time.perf_counter() - t:.0f} s", file=sys.stderr)
    return results, groups


def alignment_only(
    quick: bool,
    runs: int,
    jitter_ms: float,
    json_path: Path | None,
    policies: dict[str, FusionSettings] | None = None,
    error_model: ErrorModel = DEFAULT_ERROR_MODEL,
) -> int:
    """``--alignment``: every scenario under every alignment policy; prints the table."""
    results: dict[str, list[dict[str, dict[str, float]]]] = {}
    groups: dict[str, list[str]] = {}
    for scenario in scenarios(quick):
        groups.setdefault(scenario.group, []).append(scenario.name)
        t = time.perf_counter()
        results[scenario.name] = [
            run_alignment(scenario, seed, KinectV2Params(), jitter_ms, policies, error_model)
            for seed in range(runs)
        ]
        print(f"  {scenario.name}: {time.perf_counter() - t:.0f} s", file=sys.stderr)
    summary = print_alignment(results, groups, jitter_ms)
    if json_path:
        json_path.write_text(json.dumps({"summary": summary, "runs": results}, indent=1))
    return 0
