"""The feed's cost per fused frame: building the message and encoding it, for B people.

Median of many runs over one realistic frame: B ``FusedPerson`` (``ProceduralPerformer``
joints, two joints unknown, 10 sources, random confidences and source masks), built by
``protocol.feed.frame_json`` and encoded by ``server.broadcast.encode_message`` exactly as the
server publishes it; ``json.dumps`` of the same message is timed beside it for comparison.
``python -m bench load --encode-only`` prints the table.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.views import FusedPerson
from skelfuse.protocol.feed import frame_json
from skelfuse.server.broadcast import encode_message

SOURCES = tuple(f"load-{k:02d}" for k in range(1, 11))


@dataclass(frozen=True, slots=True)
class EncodeTiming:
    bodies: int
    runs: int
    message_bytes: int
    build_us: float  # frame_json
    encode_us: float  # encode_message, JSON text as served
    build_encode_us: float  # both, as publish does per variant
    json_dumps_us: float  # the standard library on the same message, for comparison
    msgpack_us: float  # encode_message, msgpack variant


def sample_frame(bodies: int, seed: int = 1) -> FusedFrame:
    """One fused frame of ``bodies`` people as fusion gives it (world metres, NaN unknown)."""
    rng = np.random.default_rng(seed)
    joints = ProceduralPerformer(bodies).joints_at(1.0)
    persons = []
    for b in range(bodies):
        person_joints = joints[b].copy()
        person_joints[[15, 19]] = np.nan  # the feet of a person standing behind furniture
        confidence = rng.uniform(0.2, 1.0, len(person_joints))
        confidence[[15, 19]] = 0.0
        masks = rng.integers(1, 2 ** len(SOURCES), len(person_joints)).astype(np.int64)
        persons.append(
            FusedPerson(b + 1, person_joints, confidence, SOURCES, (), masks, (SOURCES[2],))
        )
    return FusedFrame(1042, 1_763_712_345.123456, 1_763_712_345.15, tuple(persons), ())


def median_us(fn: Callable[[], object], runs: int) -> float:
    """Median wall time of ``fn()`` in µs over ``runs`` calls, after up to 200 warm-up calls."""
    for _ in range(min(runs, 200)):  # warm-up
        fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e6


def encode_timing(bodies: int = 6, runs: int = 5000) -> EncodeTiming:
    """Median µs per fused frame of ``bodies`` people over ``runs`` runs of each stage."""
    frame = sample_frame(bodies)
    sent_at_s = 1_763_712_345.16
    message = frame_json(frame, False, sent_at_s)
    text = encode_message(message, binary=False)
    return EncodeTiming(
        bodies,
        runs,
        len(text.encode() if isinstance(text, str) else text),
        median_us(lambda: frame_json(frame, False, sent_at_s), runs),
        median_us(lambda: encode_message(message, binary=False), runs),
        median_us(lambda: encode_message(frame_json(frame, False, sent_at_s), False), runs),
        median_us(lambda: json.dumps(message, allow_nan=False, separators=(",", ":")), runs),
        median_us(lambda: encode_message(message, binary=True), runs),
    )


def print_encode(timing: EncodeTiming) -> None:
    """The feed cost table (Markdown, as in docs/benchmarks.md)."""
    t = timing
    print(
        f"\nFeed message per fused frame, {t.bodies} people ({t.message_bytes} bytes of JSON), "
        f"median of {t.runs} runs\n"
    )
    print("| build (`frame_json`) µs | JSON encode µs | build + encode µs | target "
          "| `json.dumps` µs (for comparison) | msgpack encode µs |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    print(
        f"| {t.build_us:.1f} | {t.encode_us:.1f} | {t.build_encode_us:.1f} | ≤ 100 | "
        f"{t.json_dumps_us:.1f} | {t.msgpack_us:.1f} |"
    )
