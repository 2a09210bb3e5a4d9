"""The server's cost per incoming frame: ``protocol.wire.decode`` of one B-body ``frame``.

Median of many runs over realistic encoded frames: B ``ProceduralPerformer`` people in a sensor's
frame, every joint TRACKED as the load bench's agents send them, and the same frame with the
hand tips and thumbs NOT_TRACKED (NaN) and the feet INFERRED, as a real sensor sends them. Timed
beside it: ``msgpack.unpackb`` alone with decode's limits (the floor), and the precise
field-by-field checks after that unpack (``decode_frame_precisely``, which was the whole frame
decode before the bulk path). ``decode`` takes its msgspec path (``protocol.wire_canonical``)
for these frames when msgspec is installed (``server`` extra), else the msgpack bulk path.
``python -m bench load --decode-only`` prints the table.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgpack
import numpy as np

from bench.live.encode import median_us
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.protocol import wire_canonical
from skelfuse.protocol.wire import Body, Frame, decode, decode_frame_precisely, encode

HAND_JOINTS = [21, 22, 23, 24]  # HandTipLeft, ThumbLeft, HandTipRight, ThumbRight
FOOT_JOINTS = [15, 19]


@dataclass(frozen=True, slots=True)
class DecodeTiming:
    bodies: int
    not_tracked: bool  # hand tips and thumbs NOT_TRACKED
    runs: int
    message_bytes: int
    decode_us: float  # protocol.wire.decode, as the server calls it
    precise_us: float  # unpack + the precise checks alone (the decode before the bulk path)
    unpack_us: float  # msgpack.unpackb with decode's limits, no checks


def sample_message(bodies: int, not_tracked: bool, seed: int = 1) -> bytes:
    """One encoded ``frame`` of ``bodies`` people 2-4 m in front of a sensor."""
    joints = ProceduralPerformer(bodies).joints_at(1.0).astype(np.float32)
    joints[..., 2] += 3.0  # world → in front of the sensor (+Z forward), metres
    rng = np.random.default_rng(seed)
    out = []
    for b in range(bodies):
        states = np.full(len(joints[b]), 2, dtype=np.uint8)
        person = joints[b] + rng.normal(0.0, 0.01, joints[b].shape).astype(np.float32)
        if not_tracked:
            states[FOOT_JOINTS] = 1
            states[HAND_JOINTS] = 0
            person[HAND_JOINTS] = np.nan
        out.append(Body(72057594037928000 + b, person, states))
    return encode(Frame(1042, 1_763_712_345_123_456_789, tuple(out), (0.0, 1.0, 0.0, 1.1)))


def decode_timing(bodies: int = 6, not_tracked: bool = False, runs: int = 5000) -> DecodeTiming:
    """Median µs per ``frame`` of ``bodies`` people over ``runs`` runs of each stage."""
    buf = sample_message(bodies, not_tracked)

    def unpack() -> dict[str, object]:  # decode's own call, limits included
        raw: dict[str, object] = msgpack.unpackb(
            buf, raw=False, strict_map_key=True, max_array_len=64, max_map_len=32,
            max_str_len=4096, max_bin_len=4096, max_ext_len=0,
        )  # fmt: skip
        return raw

    return DecodeTiming(
        bodies,
        not_tracked,
        runs,
        len(buf),
        median_us(lambda: decode(buf), runs),
        median_us(lambda: decode_frame_precisely(unpack()), max(runs // 10, 200)),
        median_us(unpack, runs),
    )


def print_decode(timings: list[DecodeTiming]) -> None:
    """The decode cost table (Markdown, as in docs/benchmarks.md)."""
    path = "msgspec" if wire_canonical.ENABLED else "msgpack bulk (msgspec not installed)"
    print(
        f"\nDecode + validate one incoming frame ({path} path), median of {timings[0].runs} runs\n"
    )
    print("| frame | bytes | `decode` µs | target | precise checks µs (before) "
          "| msgpack unpack µs (floor) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    for t in timings:
        kind = "hands NOT_TRACKED" if t.not_tracked else "all TRACKED"
        print(
            f"| {t.bodies} bodies, {kind} | {t.message_bytes} | {t.decode_us:.1f} | ≤ 20 "
            f"| {t.precise_us:.1f} | {t.unpack_us:.1f} |"
        )
