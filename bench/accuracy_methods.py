"""The fusion methods the accuracy benchmark compares: ``FusionSettings`` variants, each row
adding one term to the one before."""

from __future__ import annotations

from dataclasses import replace

from skelfuse.server.settings import FusionSettings

# Report A's tracking-state weights and nothing more: the baseline every other row builds on.
BASE = FusionSettings(
    use_bone_length=False,
    use_range_of_motion=False,
    use_facing=False,
    use_distance=False,
    use_mirror_correction=False,
    correct_view_yaw=False,
    filter="none",
    enforce_bone_lengths=False,
)
BONE = replace(BASE, use_bone_length=True)  # the baseline + bone-length weights (report A's own)
_ROM = replace(BONE, use_range_of_motion=True)
_MIRROR = replace(_ROM, use_mirror_correction=True)
_FACING = replace(_MIRROR, use_facing=True)
_DISTANCE = replace(_FACING, use_distance=True)
METHODS: dict[str, FusionSettings] = {
    "plain mean": replace(BASE, state_weights=(0.0, 1.0, 1.0)),
    "tracking-state weights (report A baseline)": BASE,
    "+ bone length": BONE,
    "+ range of motion": _ROM,
    "+ mirrored-view correction": _MIRROR,
    "+ facing": _FACING,
    "+ distance (off by default)": _DISTANCE,
    "full (defaults): + facing, Kalman CA filter, bone-length fit": FusionSettings(),
    "full, One Euro filter instead (the default before)": FusionSettings(filter="one_euro"),
    "full, Kalman CV filter instead": FusionSettings(filter="kalman"),
}
BASELINE = "tracking-state weights (report A baseline)"
FULL = "full (defaults): + facing, Kalman CA filter, bone-length fit"
BEST_SINGLE = "best single sensor (oracle, per run)"
