"""What joint rotations in the feed cost the server per fused frame, for B people.

``Broadcaster.publish`` of one realistic frame (``bench.live.encode.sample_frame``) to a plain
JSON client alone (the default feed), and to the same client plus one that asked for
``?rotations=1`` (the rotations computed once, then that variant built and encoded); the
difference is the extra cost per frame, however many clients ask. The two are timed in
alternating rounds (A, B, A, B...) so that a loaded machine slows both alike; each round's
figure is the median of ``--runs`` calls, and the table gives the median of the rounds.

Times are the thread's CPU time (``time.thread_time``), not the wall's: on a loaded machine a
call of a few milliseconds spans several of the scheduler's slices, and its wall time then
measures the other processes (at load 16 on 2 cores the median wall time of the rotations was
ten times their CPU time, the default publish's barely more).

    python -m bench feed_rotations --bodies 6 --rounds 5 --runs 300
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from bench.live.encode import sample_frame
from skelfuse.fusion.engine import FusedFrame
from skelfuse.server.broadcast import Broadcaster, Variant, persons_orientations


def publish_us(frame: FusedFrame, variants: list[Variant], runs: int) -> float:
    """Median µs of one ``publish`` of ``frame`` to one client per variant."""
    broadcaster = Broadcaster()
    clients = [broadcaster.add(v, "bench", 0.0) for v in variants]
    times = []
    for k in range(runs):
        start = time.thread_time()
        broadcaster.publish(frame, 1_763_712_345.0 + k, float(k))
        times.append(time.thread_time() - start)
        for client in clients:
            client.take()
    return statistics.median(times) * 1e6


def orientations_us(frame: FusedFrame, runs: int) -> float:
    """Median µs of the rotations alone (``persons_orientations``)."""
    times = []
    for _ in range(runs):
        start = time.thread_time()
        persons_orientations(frame.persons)
        times.append(time.thread_time() - start)
    return statistics.median(times) * 1e6


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bodies", type=int, default=6)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--runs", type=int, default=300)
    args = parser.parse_args(argv)
    frame = sample_frame(args.bodies)
    plain = [Variant(False, False)]
    both = [Variant(False, False), Variant(False, False, True)]
    publish_us(frame, both, 50)  # warm-up
    default, rotations, alone = [], [], []
    for _ in range(args.rounds):
        default.append(publish_us(frame, plain, args.runs))
        rotations.append(publish_us(frame, both, args.runs))
        alone.append(orientations_us(frame, args.runs))
    a, b = statistics.median(default), statistics.median(rotations)
    print(f"load average {os.getloadavg()[0]:.1f}, {args.bodies} people, "
          f"{args.rounds} rounds x {args.runs} runs (medians)")  # fmt: skip
    print(
        "| publish: default client µs | + a rotations client µs | extra µs | rotations alone µs |"
    )
    print("|---|---|---|---|")
    print(f"| {a:.0f} | {b:.0f} | {b - a:.0f} | {statistics.median(alone):.0f} |")
