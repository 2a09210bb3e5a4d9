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
    """A take from :class:`fusion.hub.FusedFrame` objects (duck-typed: ``t_s``, ``persons``)."""
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


def resample(track: PersonTrack, fps: float, max_gap_s: float = 0.25) -> tuple[F64, F64, F64]:
    """The track on a regular clock (for BVH and C3D, which need a fixed frame rate).

    Joints are interpolated linearly between fused samples no more than ``max_gap_s`` apart;
    elsewhere they are NaN (confidence 0).

    Returns:
        times (N,) from the track's first instant at 1/fps steps, joints (N, 25, 3),
        confidence (N, 25).
    """
    if fps <= 0:
        raise TakeError(f"frame rate must be positive, got {fps}")
    t = track.times_s
    count = int(np.floor((t[-1] - t[0]) * fps + 1e-9)) + 1
    grid = t[0] + np.arange(count) / fps
    after = np.clip(np.searchsorted(t, grid, side="left"), 0, t.size - 1)
    before = np.clip(after - 1, 0, t.size - 1)
    exact = np.isclose(t[after], grid, atol=1e-9)
    before = np.where(exact, after, before)
    span = t[after] - t[before]
    alpha = np.where(span > 0, (grid - t[before]) / np.where(span > 0, span, 1.0), 0.0)
    ok = exact | (span <= max_gap_s)
    a = alpha[:, None, None]
    joints = (1 - a) * track.joints[before] + a * track.joints[after]
    confidence = np.minimum(track.confidence[before], track.confidence[after])
    joints[~ok] = np.nan
    confidence[~ok] = 0.0
    confidence[~np.isfinite(joints).all(axis=2)] = 0.0
    return grid, joints, confidence
