"""``python -m bench NAME [args]``: run one benchmark (its ``main(argv)``); the list without NAME.

Run from the repository root, so that ``bench`` imports; ``python -m bench NAME --help`` gives
a benchmark's own arguments.
"""

from __future__ import annotations

import importlib
import sys

BENCHMARKS: dict[str, tuple[str, str]] = {
    "accuracy": ("accuracy.compare", "every fusion method against simulated ground truth"),
    "alignment_horizons": (
        "accuracy.alignment_horizons",
        "how far late views are carried, with jitter",
    ),
    "alignment_waits": ("accuracy.alignment_waits", "the live rig's alignment wait per policy"),
    "learning": (
        "accuracy.learning",
        "errors learned from the rig: fused vs the oracle, learned vs true error, a moved sensor",
    ),
    "lag": ("accuracy.lag", "lag of the fused output against the truth, per joint group"),
    "lead_lag": ("accuracy.lead_lag", "lead / lag of the fused output against truth and views"),
    "calibration": ("calibration.methods", "how well each calibration method places sensors"),
    "drift": ("calibration.drift", "a bumped sensor flagged in time, nothing flagged otherwise"),
    "load": ("live.load", "the real server under N agents × 30 fps × B bodies and 21 clients"),
    "many_clients": ("live.many_clients", "many WebSocket viewers on one server"),
    "calibration_stall": ("live.calibration_stall", "the live server's pace while it calibrates"),
    "malformed_burst": ("live.malformed_burst", "the feed under a burst of malformed messages"),
    "body_limit": ("live.body_limit", "server memory under an upload far over the body limit"),
    "feed_rotations": ("live.feed_rotations", "what joint rotations in the feed cost per frame"),
    "outputs": ("live.outputs", "OSC, VMC and LSL outputs at the fused rate on loopback"),
    "nats_fanout": ("live.nats_fanout", "NATS fan-out of many rooms through one hub"),
    "replay": ("recording.replay", "replay speed and BVH round trip on a simulated recording"),
    "mono_accuracy": ("mono.accuracy", "one ordinary camera, and three fused, on the real clip"),
    "mono_source": ("mono.source", "the mono source's CPU per frame (in .venv-mono)"),
    "floor_depth": ("mono.floor_depth", "depth from the floor against PnP's, per camera"),
    "moving_sensors": ("moving.sensors", "head-mounted sensors: erroneous frames, fused error"),
    "reprojection": ("moving.reprojection", "depth re-projected into a level reference camera"),
}
"""Benchmark name → (module under ``bench``, what it measures)."""


def usage() -> str:
    width = max(map(len, BENCHMARKS))
    rows = [f"  {name:<{width}}  {what}" for name, (_, what) in BENCHMARKS.items()]
    return "\n".join(["usage: python -m bench NAME [args]  (NAME --help for its own)", *rows])


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0
    name, *rest = argv
    if name not in BENCHMARKS:
        print(f"unknown benchmark {name!r}\n{usage()}", file=sys.stderr)
        return 2
    module = importlib.import_module(f"bench.{BENCHMARKS[name][0]}")
    sys.argv[0] = f"python -m bench {name}"  # argparse's prog in the benchmark's --help
    result = module.main(rest)
    return result if isinstance(result, int) else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
