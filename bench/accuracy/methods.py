"""The fusion methods the accuracy benchmark compares: ``FusionSettings`` variants, each row
adding one term to the one before."""

from __future__ import annotations

from dataclasses import replace

from skelfuse.fusion.settings import (
    BoneSettings,
    FusionSettings,
    LearningSettings,
    MirrorSettings,
    SmoothingSettings,
    WeightSettings,
)

# Report A's tracking-state weights and nothing more: the baseline every other row builds on.
BASE = FusionSettings(
    weights=WeightSettings(bone_length=False, range_of_motion=False, view_bins=False),
    learning=LearningSettings(enabled=False, robust_dof=0.0),
    mirror=MirrorSettings(enabled=False),
    smoothing=SmoothingSettings(filter="none"),
    bones=BoneSettings(enforce=False),
)
BONE = replace(
    BASE, weights=replace(BASE.weights, bone_length=True)
)  # the baseline + bone-length weights (report A's own)
_ROM = replace(BONE, weights=replace(BONE.weights, range_of_motion=True))
_MIRROR = replace(_ROM, mirror=replace(_ROM.mirror, enabled=True))
_BINS = replace(_MIRROR, weights=replace(_MIRROR.weights, view_bins=True))
_ROBUST = replace(_BINS, learning=replace(_BINS.learning, robust_dof=4.0))
_LEARNED = replace(_ROBUST, learning=replace(_ROBUST.learning, enabled=True))
METHODS: dict[str, FusionSettings] = {
    "plain mean": replace(BASE, weights=replace(BASE.weights, state_weights=(0.0, 1.0, 1.0))),
    "tracking-state weights (report A baseline)": BASE,
    "+ bone length": BONE,
    "+ range of motion": _ROM,
    "+ mirrored-view correction": _MIRROR,
    "+ where each sensor stands (priors' bins)": _BINS,
    "+ Student-t for views far off the others": _ROBUST,
    "+ errors learned from the rig": _LEARNED,
    "full (defaults): + learned errors, Kalman CA filter, bone-length fit": FusionSettings(),
    "full, One Euro filter instead (the default before)": FusionSettings(
        smoothing=SmoothingSettings(filter="one_euro")
    ),
    "full, Kalman CV filter instead": FusionSettings(smoothing=SmoothingSettings(filter="kalman")),
}
BASELINE = "tracking-state weights (report A baseline)"
FULL = "full (defaults): + learned errors, Kalman CA filter, bone-length fit"
BEST_SINGLE = "best single sensor (oracle, per run)"
