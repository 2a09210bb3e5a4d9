"""The accuracy benchmark's metrics: fused persons matched to the truth, and what one method's
run adds up to (MPJPE, erroneous frames, bone CV, jitter, id switches, duplicates, coverage)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from skelfuse.fusion.identity import TRUNK_JOINTS
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, bone_lengths

MATCH_GATE_M = 1.0
ERROR_JOINTS = (JointId.HEAD, JointId.HAND_LEFT, JointId.HAND_RIGHT, JointId.ANKLE_LEFT,
                JointId.ANKLE_RIGHT)  # fmt: skip
ERROR_LIMIT_M = 0.10
SETTLE_FRAMES = 60
"""Fused frames (2 s at 30 Hz) left out of the settled bone CV."""
FUSED_HZ = 30.0
"""The benchmark's fused frame rate (the hub's default output grid)."""
FloatArray = npt.NDArray[np.float64]


@dataclass
class Log:
    """Everything one method produced over one run, for the metrics."""

    errors: list[FloatArray] = field(default_factory=list)  # per (frame, person): (25,) metres
    expected: int = 0  # (frame, person) pairs in the truth
    frames: int = 0
    duplicate_frames: int = 0
    bones: dict[int, list[FloatArray]] = field(default_factory=dict)  # truth person → (24,)
    error_vectors: dict[int, list[tuple[int, FloatArray | None]]] = field(default_factory=dict)
    ids: dict[int, list[int]] = field(default_factory=dict)
    label_total: int = 0  # (sensor × frame) labelling decisions
    label_wrong: int = 0
    # Per truth person: (frame index, any view wrong, a front or side view sees them) per frame.
    label_frames: dict[int, list[tuple[int, bool, bool]]] = field(default_factory=dict)

    def add(
        self,
        frame_index: int,
        persons: list[tuple[int, FloatArray]],
        truth: FloatArray,
        labels: dict[int, list[tuple[bool, bool]]] | None = None,
    ) -> None:
        """One fused frame: the published (id, (25, 3) joints) against the truth (P, 25, 3);
        ``labels``: per published id, each view's (swapped back by fusion, mirrored in truth)."""
        self.frames += 1
        self.expected += truth.shape[0]
        if len(persons) > truth.shape[0]:
            self.duplicate_frames += 1
        matched: dict[int, tuple[int, FloatArray]] = {}
        if persons:
            cost = np.array([[_trunk(p[1], t) for t in truth] for p in persons])
            rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e6))
            for r, c in zip(rows, cols, strict=True):
                if cost[r, c] <= MATCH_GATE_M:
                    matched[int(c)] = persons[r]
        for index in range(truth.shape[0]):
            vectors = self.error_vectors.setdefault(index, [])
            if index not in matched:
                vectors.append((frame_index, None))
                continue
            person_id, joints = matched[index]
            diff = joints - truth[index]
            self.errors.append(np.linalg.norm(diff, axis=1))
            self.bones.setdefault(index, []).append(bone_lengths(joints))
            vectors.append((frame_index, diff))
            ids = self.ids.setdefault(index, [])
            if not ids or ids[-1] != person_id:
                ids.append(person_id)
            decisions = (labels or {}).get(person_id, [])
            if decisions:
                wrong = sum(decided != true for decided, true in decisions)
                self.label_total += len(decisions)
                self.label_wrong += wrong
                front = any(not true for _, true in decisions)
                self.label_frames.setdefault(index, []).append((frame_index, wrong > 0, front))

    def summary(self) -> dict[str, float]:
        if not self.errors:
            nan = math.nan
            return {"mpjpe_mm": nan, "p95_mm": nan, "coverage": 0.0, "erroneous": 1.0,
                    "bone_cv": nan, "bone_cv_settled": nan, "jitter_mm": nan, "id_switches": 0.0,
                    "duplicates": 0.0, "wrong_labels": nan, "wrong_after_front_s": nan}  # fmt: skip
        errors = np.stack(self.errors)
        flat = errors[np.isfinite(errors)]
        key = errors[:, list(ERROR_JOINTS)]
        bad = (~np.isfinite(key) | (key > ERROR_LIMIT_M)).any(axis=1)
        erroneous = (bad.sum() + (self.expected - len(self.errors))) / max(self.expected, 1)
        cvs: list[float] = []
        settled: list[float] = []
        for series in self.bones.values():
            lengths = np.stack(series)
            for skip, out in ((0, cvs), (SETTLE_FRAMES, settled)):
                part = lengths[skip:]
                if len(part) < 2:
                    continue
                with np.errstate(invalid="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN bones
                    cv = np.nanstd(part, axis=0) / np.nanmean(part, axis=0)
                out.extend(cv[np.isfinite(cv)].tolist())
        jitter = []
        for vectors in self.error_vectors.values():
            for (i0, a), (_, b), (i2, c) in zip(vectors, vectors[1:], vectors[2:], strict=False):
                if a is None or b is None or c is None or i2 - i0 != 2:
                    continue
                second = np.linalg.norm(a - 2 * b + c, axis=1)
                jitter.extend(second[np.isfinite(second)].tolist())
        return {
            "mpjpe_mm": float(flat.mean() * 1000),
            "p95_mm": float(np.percentile(flat, 95) * 1000),
            "coverage": flat.size / (self.expected * JOINT_COUNT),
            "erroneous": float(erroneous),
            "bone_cv": float(np.mean(cvs)) if cvs else math.nan,
            "bone_cv_settled": float(np.mean(settled)) if settled else math.nan,
            "jitter_mm": float(np.mean(jitter) * 1000) if jitter else math.nan,
            "id_switches": float(sum(max(len(ids) - 1, 0) for ids in self.ids.values())),
            "duplicates": self.duplicate_frames / max(self.frames, 1),
            "wrong_labels": self.label_wrong / self.label_total if self.label_total else math.nan,
            "wrong_after_front_s": self._longest_wrong_after_front_s(),
        }

    def _longest_wrong_after_front_s(self) -> float:
        """The longest run of fused frames (in seconds at 30 Hz) in which some view of a person
        is labelled wrong, counted from the first frame a front or side view sees them."""
        longest = 0
        for frames in self.label_frames.values():
            run, seen_front, last = 0, False, None
            for frame_index, wrong, front in frames:
                seen_front = seen_front or front
                if last is not None and frame_index != last + 1:
                    run = 0
                last = frame_index
                run = run + 1 if wrong and seen_front else 0
                longest = max(longest, run)
        return longest / FUSED_HZ


def _trunk(a: FloatArray, b: FloatArray) -> float:
    """Mean distance (m) between two (25, 3) skeletons on the trunk joints both have, else inf."""
    pa, pb = a[TRUNK_JOINTS], b[TRUNK_JOINTS]
    both = np.isfinite(pa).all(axis=1) & np.isfinite(pb).all(axis=1)
    return float(np.linalg.norm(pa[both] - pb[both], axis=1).mean()) if both.any() else math.inf
