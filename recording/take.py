"""Fused motion as arrays, per person: what the exporters take.

A take comes from fused frames (a replayed recording, or the live hub) or from a JSON Lines
file of fused frames (``skelfuse replay --out``, or WebSocket messages saved one per line by a
client during a live session).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT

F64 = npt.NDArray[np.float64]


class TakeError(ValueError):
    """Fused data that cannot be exported; the message says why."""


@dataclass(frozen=True, slots=True)
class PersonTrack:
    """One person over time (world frame, +Y up, metres).

    times_s: (T,) float64 fused instants, increasing.
    joints: (T, 25, 3) float64, NaN where the joint is unknown.
    confidence: (T, 25) float64 in [0, 1], 0 where NaN.
    """

    person_id: int
    times_s: F64
    joints: F64
    confidence: F64


@dataclass(frozen=True, slots=True)
class Take:
    persons: dict[int, PersonTrack]

    @property
    def start_s(self) -> float:
        return min((float(p.times_s[0]) for p in self.persons.values()), default=0.0)

    @property
    def end_s(self) -> float:
        return max((float(p.times_s[-1]) for p in self.persons.values()), default=0.0)

    def main_person(self) -> PersonTrack:
        """The person seen in the most frames (what BVH exports by default)."""
        if not self.persons:
            raise TakeError("nobody was fused in this take: nothing to export")
        return max(self.persons.values(), key=lambda p: (p.times_s.size, -p.person_id))


class _Builder:
    def __init__(self) -> None:
        self.rows: dict[int, tuple[list[float], list[F64], list[F64]]] = {}

    def add(self, person_id: int, t_s: float, joints: F64, confidence: F64) -> None:
        times, js, cs = self.rows.setdefault(person_id, ([], [], []))
        if times and t_s <= times[-1]:
            return
        times.append(t_s)
        js.append(joints)
        cs.append(confidence)

    def build(self) -> Take:
        persons = {
            pid: PersonTrack(pid, np.asarray(t, dtype=np.float64), np.stack(j), np.stack(c))
            for pid, (t, j, c) in sorted(self.rows.items())
        }
        return Take(persons)


def take_from_frames(frames: Iterable[object]) -> Take:
    """A take from :class:`fusion.engine.FusedFrame` objects (duck-typed: ``t_s``, ``persons``)."""
    builder = _Builder()
    for frame in frames:
        t_s = float(frame.t_s)  # type: ignore[attr-defined]
        for person in frame.persons:  # type: ignore[attr-defined]
            joints = np.asarray(person.joints, dtype=np.float64).reshape(JOINT_COUNT, 3)
            confidence = np.asarray(person.confidence, dtype=np.float64).reshape(JOINT_COUNT)
            builder.add(int(person.person_id), t_s, joints, confidence)
    return builder.build()


def take_from_jsonl(path: str | Path) -> Take:
    """A take from fused frames saved one JSON message per line (other lines are skipped)."""
    builder = _Builder()
    path = Path(path)
    with path.open(encoding="utf-8") as lines:
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                message = json.loads(line)
            except json.JSONDecodeError as exc:
                raise TakeError(f"{path}:{number}: not JSON ({exc.msg})") from exc
            if not isinstance(message, dict) or message.get("type") != "frame":
                continue
            try:
                t_s = float(message["t"])
                for person in message["persons"]:
                    joints = np.array(
                        [[np.nan] * 3 if j is None else j for j in person["joints"]],
                        dtype=np.float64,
                    ).reshape(JOINT_COUNT, 3)
                    confidence = np.asarray(person["confidence"], dtype=np.float64)
                    builder.add(int(person["id"]), t_s, joints, confidence.reshape(JOINT_COUNT))
            except (KeyError, TypeError, ValueError) as exc:
                raise TakeError(f"{path}:{number}: not a fused frame message ({exc})") from exc
    return builder.build()


MAX_GAP_S = 0.25
"""Longest interval between two fused samples of a joint that resampling bridges (seconds)."""

ON_SAMPLE_S = 1e-6
"""An instant this close to a fused sample takes that sample as is (seconds). Times are handled
relative to the track's first instant: Unix-epoch seconds (~1.8e9) carry 2.4e-7 s steps."""


def frame_count(start_s: float, end_s: float, fps: float) -> int:
    """Instants ``start_s + k / fps`` up to ``end_s`` (inclusive, to :data:`ON_SAMPLE_S`).

    Raises:
        TakeError: ``fps`` is not positive or ``end_s`` is before ``start_s``.
    """
    if not fps > 0:
        raise TakeError(f"frame rate must be positive, got {fps}")
    if end_s < start_s:
        raise TakeError(f"the take ends ({end_s}) before it starts ({start_s})")
    return int(np.floor((end_s - start_s + ON_SAMPLE_S) * fps)) + 1


def sample_at(
    track: PersonTrack, start_s: float, offsets_s: F64, max_gap_s: float = MAX_GAP_S
) -> tuple[F64, F64]:
    """The track at instants ``start_s + offsets_s``, joint by joint.

    A joint is taken from a fused sample within :data:`ON_SAMPLE_S` of the instant, else
    interpolated linearly between its two fused samples around the instant when they are at
    most ``max_gap_s`` apart (a joint unknown in a few fused frames is bridged from its own
    neighbours); elsewhere (longer gaps, before the track's first or after its last sample of
    that joint) it is NaN with confidence 0. Confidence is the lower of the two neighbours'.

    Args:
        track: the fused person.
        start_s: Unix seconds the offsets count from (kept apart so that epoch-scale times
            lose no precision).
        offsets_s: (N,) seconds after ``start_s``, any order.
        max_gap_s: longest interval bridged.

    Returns:
        joints (N, 25, 3) metres, NaN where empty; confidence (N, 25), 0 where empty.
    """
    offsets = np.asarray(offsets_s, dtype=np.float64)
    times = track.times_s - start_s
    joints = np.full((offsets.size, JOINT_COUNT, 3), np.nan)
    confidence = np.zeros((offsets.size, JOINT_COUNT))
    known = np.asarray(np.isfinite(track.joints).all(axis=2), dtype=bool)
    for j in range(JOINT_COUNT):
        rows = np.flatnonzero(known[:, j])
        if rows.size == 0:
            continue
        t = times[rows]
        after = np.searchsorted(t, offsets - ON_SAMPLE_S, side="left")
        inside = after < t.size
        on = inside & (np.abs(t[np.minimum(after, t.size - 1)] - offsets) <= ON_SAMPLE_S)
        a = np.minimum(after, t.size - 1)
        b = np.maximum(after - 1, 0)
        between = inside & ~on & (after > 0) & (t[a] - t[b] <= max_gap_s)
        alpha = np.where(between, (offsets - t[b]) / np.where(between, t[a] - t[b], 1.0), 0.0)
        alpha = np.where(on, 1.0, alpha)
        ok = on | between
        first, second = track.joints[rows[b], j], track.joints[rows[a], j]
        value = first + alpha[:, None] * (second - first)
        joints[ok, j] = value[ok]
        c_first, c_second = track.confidence[rows[b], j], track.confidence[rows[a], j]
        confidence[ok, j] = np.where(on, c_second, np.minimum(c_first, c_second))[ok]
    return joints, confidence


def resample(track: PersonTrack, fps: float, max_gap_s: float = MAX_GAP_S) -> tuple[F64, F64, F64]:
    """The track on a regular clock (for BVH and C3D, which need a fixed frame rate).

    The clock starts at the track's first fused instant; each joint is sampled as
    :func:`sample_at` says (linear within gaps up to ``max_gap_s``, NaN beyond).

    Returns:
        times (N,) Unix seconds from the track's first instant at 1/fps steps, joints
        (N, 25, 3), confidence (N, 25).

    Raises:
        TakeError: ``fps`` is not positive.
    """
    start = float(track.times_s[0])
    offsets = np.arange(frame_count(start, float(track.times_s[-1]), fps)) / fps
    joints, confidence = sample_at(track, start, offsets, max_gap_s)
    return start + offsets, joints, confidence
