"""The mirror labels' choice and its anatomical evidence, for :func:`~skelfuse.fusion.labels.
label_views`.

:func:`scored_labels` chooses every view's labelling and measures how much each view's anatomy
speaks against it (:func:`view_evidence`), which ``mirror.redecide`` sums per person, in one
compiled call (:func:`skelfuse.fusion.mirror.score`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.mirror import Scored, score
from skelfuse.fusion.mirror_scores import evidence_loop, slots
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import plain

FloatArray = npt.NDArray[np.float64]

__all__ = ["Scored", "evidence_against", "scored_labels", "view_evidence"]


def scored_labels(
    joints: FloatArray,
    sensor_positions: FloatArray,
    counts: Sequence[int],
    references: Sequence[FloatArray | None],
    reference_facings: FloatArray,
    previous: npt.NDArray[np.intp],
    settings: FusionSettings,
    need_rom: bool,
    want_evidence: bool,
) -> Scored:
    """Every view's labelling, and each view's evidence against it when ``want_evidence``.

    Args:
        joints: (N, 25, 3) all persons' views, each person's consecutive; metres, world.
        sensor_positions: (N, 3) metres, world (NaN rows: unknown).
        counts: views per person (P).
        references: each person's last fused skeleton (25, 3), or None before its first fusion.
        reference_facings: (P, 3) each person's facing (NaN: unknown).
        previous: (N,) each view's last decision (1, 0, −1 unknown).
        settings: the mirror terms' weights and the range-of-motion scale.
        need_rom: the range-of-motion factors are wanted even without the anatomy term.
        want_evidence: measure the evidence (``per_view`` and ``evidence`` of the result);
            it needs the range-of-motion factors.
    """
    s = settings
    weights = (s.mirror.track_weight, s.mirror.geometry_weight_m, s.mirror.anatomy_weight_m)
    return score(
        joints,
        sensor_positions,
        counts,
        (references, reference_facings, previous),
        (*weights, s.mirror.hysteresis_m, s.weights.rom_scale_deg),
        need_rom=need_rom,
        want_evidence=want_evidence,
    )


def evidence_against(
    both_rom: FloatArray, mirrored: npt.NDArray[np.bool_], counts: Sequence[int]
) -> FloatArray:
    """(P,) each person's anatomical evidence against its labelling, in joints.

    Σ over the person's views of (joints out of range of motion as labelled) − (as swapped),
    a joint counting 1 − its range-of-motion factor. Agreement between views and the geometry
    term cannot tell a labelling from its reverse (turning every view over keeps the views in
    agreement and reverses the facing they imply); anatomy can: with left and right swapped,
    feet point backwards and bent knees look hyperextended. A view that does not see the legs
    (close to a sensor behind the person) adds next to nothing, however it was labelled.

    Args:
        both_rom: (N, 2, 25) range-of-motion factors of each view as reported (0) and swapped
            (1), as :func:`~skelfuse.fusion.mirror.choose_labellings` gives them.
        mirrored: (N,) the labelling chosen.
        counts: views per person.
    """
    evidence = np.empty(len(counts))
    person_of = plain(slots(tuple(counts)).person_of, np.intp)
    evidence_loop(plain(both_rom), plain(mirrored, np.bool_), person_of, np.empty(len(mirrored)),
                  evidence)  # fmt: skip
    return evidence


def view_evidence(both_rom: FloatArray, mirrored: npt.NDArray[np.bool_]) -> FloatArray:
    """(N,) each view's anatomical evidence against its labelling, in joints
    (:func:`evidence_against` before the sum over a person's views; 0 where unknown)."""
    per_view = np.empty(len(mirrored))
    evidence_loop(plain(both_rom), plain(mirrored, np.bool_),
                  np.zeros(len(mirrored), dtype=np.intp), per_view, np.empty(1))  # fmt: skip
    return per_view
