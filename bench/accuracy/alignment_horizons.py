"""How far late views are carried under an alignment policy, with and without delivery jitter.

``python -m bench alignment_horizons [--policy "views 7 ms"] [--jitter-ms 0 3] [--seed 1]``:
the quick accuracy scenarios (``bench/accuracy/scenarios.py``) fed to one production hub per
jitter exactly as ``python -m bench accuracy --alignment`` feeds them; over every fused frame, the
views carried forward and each one's horizon (instant − its newest frame). Explains where a
policy's accuracy goes on a jittery link (docs/benchmarks.md "Load", 2026-11-23 16:10).
"""

from __future__ import annotations

import argparse

import numpy as np
import numpy.typing as npt

from bench.accuracy.alignment import ALL_POLICIES, arrivals, deliver
from bench.accuracy.runner import SimulatedRig, _new_hub
from bench.accuracy.scenarios import scenarios
from skelfuse.agent.sim.kinect_model import KinectV2Params


def horizons_ms(policy: str, jitter_ms: float, seed: int) -> npt.NDArray[np.float64]:
    """Every carried view's horizon (ms) over the quick scenarios' fused frames."""
    horizons: list[float] = []
    for scenario in scenarios(True):
        rig = SimulatedRig(scenario, seed, KinectV2Params())
        hub = _new_hub(ALL_POLICIES[policy], rig.names, rig.poses)
        for arrival, capture in arrivals(list(rig.captures()), jitter_ms, seed):
            for fused in deliver(hub, capture, arrival):
                horizons += [seconds * 1000 for _, seconds in fused.extrapolated]
    return np.array(horizons)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="views 7 ms", choices=sorted(ALL_POLICIES))
    parser.add_argument("--jitter-ms", type=float, nargs="+", default=[0.0, 3.0])
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    print(f"\n`{args.policy}`, quick scenarios, seed {args.seed}\n")
    print("| jitter (mean, ms) | views carried | horizon mean / p50 / p90 (ms) | carried > 20 ms |")
    print("|---:|---:|---|---:|")
    for jitter in args.jitter_ms:
        h = horizons_ms(args.policy, jitter, args.seed)
        if not h.size:
            print(f"| {jitter:g} | 0 | — | — |")
            continue
        print(
            f"| {jitter:g} | {h.size} | {h.mean():.1f} / {np.median(h):.1f} / "
            f"{np.percentile(h, 90):.1f} | {np.mean(h > 20):.1%} |"
        )
    return 0
