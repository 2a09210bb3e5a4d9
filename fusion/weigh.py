"""Steps 5–6 of the pipeline on a batch: every view's per-joint weights, and the fusions.

:func:`weigh_and_fuse` weighs each view's joints by the body terms alone (tracking state, bone
length, range of motion: :func:`~skelfuse.fusion.confidence.body_weights`) and fuses them, which
tells where each person stands; then by where its sensor stands (facing, distance), how well it
sees each joint (``use_view_reliability``) and one Cauchy pass (``outlier_scale_m``), fusing
after each; last, the confidence apps receive and which views carried each joint.

The usual step (every person fused before, so its facing is known; the facing term alone; one
facing model and the settings' state table for every sensor; no camera that guesses depth)
runs as one compiled call with the kernels on (:mod:`skelfuse.fusion.kernels_weigh`: the same
bits); anything else, and the kernels off, runs the code below.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_weigh
from skelfuse.fusion.anatomy import corrected_yaw, facing_directions
from skelfuse.fusion.batch import ViewBatch
from skelfuse.fusion.confidence import (
    BODY_TABLES,
    as_settings,
    body_weights,
    facing_cosines,
    range_of_motion_factors,
    view_factors,
)
from skelfuse.fusion.kernels_weigh import Weighed
from skelfuse.fusion.priors import SensorPrior, distinct_priors
from skelfuse.fusion.reliability import reliability_factors
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.weighted import MIN_SHARE, cauchy_reweight, confidence_and_carriers

FloatArray = npt.NDArray[np.float64]

__all__ = ["Weighed", "weigh_and_fuse"]


def weigh_and_fuse(
    batch: ViewBatch,
    rom: FloatArray | None,
    references: FloatArray,
    track_facings: FloatArray,
    fused_once: Sequence[bool],
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None,
) -> Weighed:
    """Steps 5–6 (module docstring) for P persons' N views, labels corrected.

    Args:
        batch: the views, each person's consecutive (with ``correct_view_yaw`` their joints are
            turned in place).
        rom: (N, 25) range-of-motion factors of each view as labelled, or None (computed here
            when ``use_range_of_motion``).
        references: (P, 24) each person's reference bone lengths, metres (NaN: unknown).
        track_facings: (P, 3) each person's facing from its track, horizontal unit vectors.
        fused_once: (P,) whether each person was fused before (else its facing is taken from
            this step's first fusion).
        settings: which terms are on, and their scales.
        priors: (N,) each view's sensor prior, or None: the settings' values for every view.
    """
    s = settings
    model = _one_facing_model(s, priors)
    if (
        model is not None
        and all(fused_once)
        and batch.depth_ratios is None
        and not (s.use_distance or s.correct_view_yaw or s.use_view_reliability)
        and s.outlier_scale_m <= 0
        and kernels.enabled()
        and kernels_weigh.warmed()
    ):
        weighed = kernels_weigh.weigh_and_fuse(
            (
                batch.joints,
                batch.states,
                references if s.use_bone_length else None,
                _rom(batch, rom, s),
            ),
            (s.state_weights, s.bone_length_scale_m, BODY_TABLES[0]),
            BODY_TABLES[1],
            (batch.starts, batch.widest),
            track_facings,
            batch.sensors,
            model,
            MIN_SHARE,
        )
        if weighed is not None:
            return weighed
    known = references[batch.person_of] if np.isfinite(references).any() else None
    return _weighed(batch, rom, known, track_facings, fused_once, s, priors)


def _one_facing_model(
    settings: FusionSettings, priors: Sequence[SensorPrior] | None
) -> tuple[float, float, float] | None:
    """The facing term's (power, floor, back factor) when it is the only view factor, every view
    has the same, and every view's body terms are the settings' (the compiled call's case);
    else None.

    Steps repeat the same settings and sequence of priors (frozen objects): the answer is kept
    per sequence by the objects' identities, with the objects (so that no id is reused
    meanwhile), as :func:`~skelfuse.fusion.priors.distinct_priors` keeps its own."""
    s = settings
    if not s.use_facing:
        return None
    if priors is None:
        return (s.facing_power, s.facing_floor, s.facing_back_factor)
    key = (id(s), *map(id, priors))
    kept = _facing_models.get(key)
    if kept is None:
        if len(_facing_models) >= _KEPT:
            _facing_models.clear()
        distinct = distinct_priors(priors)[0]
        models = {p.facing(s) for p in distinct}
        one = len(models) == 1 and all(as_settings(p, s) for p in distinct)
        kept = _facing_models[key] = (s, tuple(priors), models.pop() if one else None)
    return kept[2]


_facing_models: dict[
    tuple[int, ...],
    tuple[FusionSettings, tuple[SensorPrior, ...], tuple[float, float, float] | None],
] = {}
_KEPT: Final = 64
"""Sequences of settings and priors :func:`_one_facing_model` keeps."""


def _rom(batch: ViewBatch, rom: FloatArray | None, settings: FusionSettings) -> FloatArray | None:
    """The range-of-motion factors the body terms use: ``rom``, or computed (None: term off)."""
    if not settings.use_range_of_motion:
        return None
    if rom is not None:
        return rom
    return range_of_motion_factors(batch.joints, settings.rom_scale_deg)


def _weighed(
    batch: ViewBatch,
    rom: FloatArray | None,
    references: FloatArray | None,
    track_facings: FloatArray,
    fused_once: Sequence[bool],
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None,
) -> Weighed:
    """:func:`weigh_and_fuse` term by term (any settings); ``references`` per view, or None."""
    s = settings
    weights = body_weights(batch.joints, batch.states, references, rom, s, priors)
    fused = batch.fuse(weights)

    # 5. Facing and distance: each view's factor from where the person stands and faces.
    facing = track_facings
    if not all(fused_once):
        once = np.array(fused_once, dtype=bool)
        facing = np.where(once[:, None], track_facings, facing_directions(fused))
    stands = batch.body_positions(fused)[batch.person_of]
    cosines = facing_cosines(facing[batch.person_of], stands, batch.sensors)
    if s.correct_view_yaw:
        for lo, hi in zip(batch.starts[:-1], batch.starts[1:], strict=True):
            if hi - lo > 1:
                batch.joints[lo:hi] = corrected_yaw(
                    batch.joints[lo:hi], cosines[lo:hi], s.yaw_max_deg
                )
    if s.use_facing or s.use_distance or s.correct_view_yaw:
        weights = weights * view_factors(cosines, stands, batch.sensors, s, priors)[:, None]
        fused = batch.fuse(weights)  # 6. weighted fusion
    if s.use_view_reliability:  # 5. how well each view sees each joint
        weights = weights * reliability_factors(
            batch.joints,
            cosines,
            batch.sensors,
            batch.starts.tolist(),
            s.view_lean_fraction,
            s.view_error_m,
            s.view_jitter_per_m2,
            s.view_occlusion_m,
            batch.states,
        )
        fused = batch.fuse(weights)

    if s.outlier_scale_m > 0:  # 6. one Cauchy pass where a person has several views
        several = np.array(batch.counts)[batch.person_of] > 1
        if several.any():
            reweighted = cauchy_reweight(
                batch.joints, fused[batch.person_of], weights, s.outlier_scale_m
            )
            weights = np.where(several[:, None], reweighted, weights)
            fused = batch.fuse(weights)
    padded_joints, padded_weights = batch.pad(batch.joints, np.nan), batch.pad(weights, 0.0)
    confidence, carried = confidence_and_carriers(padded_joints, padded_weights)
    return Weighed(weights, fused, cosines, confidence, carried)
