"""Which body is which person: skeleton calibration when the sensors' tracking ids do not match.

Two sensors give the same person different tracking ids, and may see a second person, or lose
one body and find it again under a new id. :func:`solve_with_body_pairing` treats every
(reference id, other id) pair seen at the same instants as a hypothesis, fits each with
:func:`skelfuse.calibration.skeleton_pose.solve_from_skeletons`, keeps the best, and pools the
hypotheses that agree with it (within :data:`AGREE_DEG` and :data:`AGREE_MM`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np

from skelfuse.calibration.errors import CalibrationError, NotEnoughCorrespondences
from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.skeleton_pose import (
    RGB_MIN_SCALE_M,
    RGB_RANSAC_THRESHOLD_M,
    SkeletonFit,
    solve_from_skeletons,
)
from skelfuse.protocol.wire import Body

MIN_PAIR_SAMPLES: Final = 30
"""Instants a body pair must share to be a hypothesis (1 s at 30 Hz)."""
AGREE_DEG: Final = 5.0
AGREE_MM: Final = 150.0
"""Two hypotheses closer than this (rotation, translation) are taken to be the same person."""
MAX_PAIRS_PER_INSTANT: Final = 9
"""Instants with more body pairs than this (a crowd) are left out: too ambiguous to help."""


DEPTH_RANSAC_THRESHOLD_M: Final = 0.10
DEPTH_MIN_SCALE_M: Final = 0.015
"""``ransac_threshold_m`` and ``min_scale_m`` for pairs of depth sensors (Kinects, the
simulator): :func:`solve_with_body_pairing`'s defaults."""


def pairing_thresholds(*sensor_types: str | None) -> tuple[float, float]:
    """``(ransac_threshold_m, min_scale_m)`` for a pair of sensors of these ``sensor_type`` s:
    the ``rgb`` (mono) settings when either is ``rgb`` (its depth rests on a guess of the body's
    size, skeleton_pose.RGB_RANSAC_THRESHOLD_M), else the depth sensors' (None: unknown type)."""
    if "rgb" in sensor_types:
        return RGB_RANSAC_THRESHOLD_M, RGB_MIN_SCALE_M
    return DEPTH_RANSAC_THRESHOLD_M, DEPTH_MIN_SCALE_M


def solve_with_body_pairing(
    ref_samples: Sequence[tuple[Body, ...]],
    other_samples: Sequence[tuple[Body, ...]],
    *,
    ransac_threshold_m: float = DEPTH_RANSAC_THRESHOLD_M,
    min_scale_m: float = DEPTH_MIN_SCALE_M,
) -> tuple[SkeletonFit, str | None]:
    """Relative pose of two sensors from their bodies, not knowing which body is which person.

    Every (reference tracking id, other tracking id) pair seen at the same instants is a
    hypothesis; each is fitted on its own, the best (lowest residual, enough joints) wins, and
    the hypotheses that agree with it (a re-acquired body under a new id is the same person)
    are pooled for the final fit. With one person in the room this is simply all instants.

    Args:
        ref_samples: per instant, the reference sensor's bodies (joints (25, 3), metres, the
            reference's sensor frame); ``()`` where it saw nobody.
        other_samples: the other sensor's bodies at the same instants (its own sensor frame).
        ransac_threshold_m, min_scale_m: as :func:`solve_from_skeletons`; with an ``rgb``
            sensor in the pair, ``skeleton_pose.RGB_RANSAC_THRESHOLD_M`` and ``RGB_MIN_SCALE_M``
            (:func:`pairing_thresholds` picks them by the sensors' types).

    Returns:
        The fit (``T_ref_from_other``, (4, 4), metres) and a note for the user when some
        pairings disagreed and were left out (None otherwise).

    Raises:
        ValueError: the two sample lists differ in length.
        NotEnoughCorrespondences: no body pair shared :data:`MIN_PAIR_SAMPLES` instants, or no
            hypothesis could be fitted (the message of the first failure says why).
    """
    groups: dict[tuple[int, int], list[tuple[Body, Body]]] = {}
    for ref_bodies, other_bodies in zip(ref_samples, other_samples, strict=True):
        if len(ref_bodies) * len(other_bodies) > MAX_PAIRS_PER_INSTANT:
            continue
        for ref_body in ref_bodies:
            for other_body in other_bodies:
                key = (ref_body.tracking_id, other_body.tracking_id)
                groups.setdefault(key, []).append((ref_body, other_body))
    candidates = {k: v for k, v in groups.items() if len(v) >= MIN_PAIR_SAMPLES}
    if not candidates:
        raise NotEnoughCorrespondences(
            "the two sensors never saw the same person for long enough "
            f"(need {MIN_PAIR_SAMPLES} common instants): walk where both can see you"
        )
    fits: dict[tuple[int, int], SkeletonFit] = {}
    errors: list[str] = []
    for key, pairs in candidates.items():
        try:
            fits[key] = _fit_pairs(pairs, ransac_threshold_m, min_scale_m)
        except CalibrationError as exc:
            errors.append(str(exc))
    if not fits:
        raise NotEnoughCorrespondences(errors[0] if errors else "no usable body pairs")
    best_key = min(fits, key=lambda k: fits[k].residual_mm / np.sqrt(max(fits[k].joints_used, 1)))
    best = fits[best_key]
    agreeing = [k for k, fit in fits.items() if _agrees(fit, best)]
    note = None
    if len(fits) > len(agreeing):
        note = (
            f"{len(fits) - len(agreeing)} body pairing(s) disagreed and were left out "
            "(more than one person in view, or mismatched bodies)"
        )
    if len(agreeing) == 1:
        return best, note
    pooled = [pair for k in agreeing for pair in candidates[k]]
    return _fit_pairs(pooled, ransac_threshold_m, min_scale_m), note


def _agrees(fit: SkeletonFit, best: SkeletonFit) -> bool:
    rotation_deg, translation_mm = pose_error(fit.T_ref_from_other, best.T_ref_from_other)
    return rotation_deg < AGREE_DEG and translation_mm < AGREE_MM


def _fit_pairs(
    pairs: list[tuple[Body, Body]], ransac_threshold_m: float, min_scale_m: float
) -> SkeletonFit:
    ref_joints = np.stack([a.joints_m for a, _ in pairs]).astype(np.float64)
    ref_states = np.stack([a.states for a, _ in pairs])
    other_joints = np.stack([b.joints_m for _, b in pairs]).astype(np.float64)
    other_states = np.stack([b.states for _, b in pairs])
    return solve_from_skeletons(
        ref_joints,
        ref_states,
        other_joints,
        other_states,
        ransac_threshold_m=ransac_threshold_m,
        min_scale_m=min_scale_m,
        rng=np.random.default_rng(0),
    )
