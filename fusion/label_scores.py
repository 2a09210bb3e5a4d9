"""The mirror labels' choice and its anatomical evidence, for :func:`~skelfuse.fusion.labels.
label_views`.

:func:`scored_labels` chooses every view's labelling
(:func:`~skelfuse.fusion.mirror.choose_labellings_and_forward`) and measures how much each
view's anatomy speaks against it (:func:`view_evidence`), which ``mirror_redecide`` sums per
person. In the usual step (every person's last skeleton and facing known) that is one compiled
call with the kernels on (:mod:`skelfuse.fusion.kernels_label_stage`: the same bits); else the
calls one by one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_label_stage, kernels_stages
from skelfuse.fusion.anatomy import ANGLE_LIMITS
from skelfuse.fusion.kernels_label_stage import Scored
from skelfuse.fusion.mirror import PERMUTATION, SWAP_PRIOR_M, choose_labellings_and_forward
from skelfuse.fusion.mirror_distances import LATERAL_JOINTS, LATERAL_SWAP
from skelfuse.fusion.mirror_labellings import SCREEN_FROM_VIEWS, SCREEN_MARGIN_M, layout, slots
from skelfuse.fusion.settings import FusionSettings

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
    if (
        kernels.enabled()
        and kernels_label_stage.warmed()
        and len(counts)
        and (need_rom or s.mirror_anatomy_weight_m > 0)
        and all(reference is not None for reference in references)
        and np.logical_and.reduce(np.isfinite(reference_facings), axis=None)
    ):  # the usual step: one compiled call
        lay = layout(tuple(counts), ((True, True),) * len(counts))
        anatomy = s.mirror_anatomy_weight_m if s.mirror_anatomy_weight_m > 0 else 0.0
        weights = (s.mirror_track_weight, s.mirror_geometry_weight_m, anatomy)
        return kernels_label_stage.scored(
            joints,
            sensor_positions,
            (lay.starts, lay.person_of, lay.first, lay.second),
            (reference_facings, np.array(references, dtype=np.float64), previous),
            (*weights, SWAP_PRIOR_M, s.mirror_hysteresis_m, 1.0),  # 1.0: ``previous`` counts
            (LATERAL_JOINTS, LATERAL_SWAP, PERMUTATION),
            (SCREEN_FROM_VIEWS, SCREEN_MARGIN_M),
            (s.rom_scale_deg, *ANGLE_LIMITS),
        )
    mirrored, factors, forward = choose_labellings_and_forward(
        joints,
        sensor_positions,
        counts,
        references,
        reference_facings,
        previous,
        geometry_weight_m=s.mirror_geometry_weight_m,
        hysteresis_m=s.mirror_hysteresis_m,
        track_weight=s.mirror_track_weight,
        anatomy_weight_m=s.mirror_anatomy_weight_m,
        rom_scale_deg=s.rom_scale_deg,
        need_rom=need_rom,
    )
    if not want_evidence or factors is None:
        return Scored(mirrored, factors, forward, None, None)
    person_of = slots(tuple(counts)).person_of
    if kernels.enabled():  # the same bits in one compiled loop
        per_view, summed = kernels_stages.view_evidence(factors, mirrored, person_of, len(counts))
    else:
        per_view = view_evidence(factors, mirrored)
        summed = np.bincount(person_of, per_view, len(counts)).astype(np.float64)
    return Scored(mirrored, factors, forward, per_view, summed)


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
    person_of = np.repeat(np.arange(len(counts)), counts)
    per_view = view_evidence(both_rom, mirrored)
    evidence: FloatArray = np.bincount(person_of, per_view, len(counts)).astype(np.float64)
    return evidence


def view_evidence(both_rom: FloatArray, mirrored: npt.NDArray[np.bool_]) -> FloatArray:
    """(N,) each view's anatomical evidence against its labelling, in joints
    (:func:`evidence_against` before the sum over a person's views; 0 where unknown)."""
    out_of_range = (1.0 - both_rom).sum(axis=2)  # (N, 2)
    rows = np.arange(len(mirrored))
    chosen = mirrored.astype(np.intp)
    per_view: FloatArray = out_of_range[rows, chosen] - out_of_range[rows, 1 - chosen]
    if not np.isfinite(per_view).all():  # (the factors are finite: kept for safety)
        per_view = np.nan_to_num(per_view)
    return per_view
