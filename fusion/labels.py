"""The mirror-labels step: which views are swapped back, remembered per body, and whole persons
swapped when they walk backwards.

:func:`label_views` asks :func:`skelfuse.fusion.mirror.choose_labellings` for every person's
labelling at once, remembers each (sensor, body)'s decision for the next step's hysteresis, and
swaps the mirrored views in place. :func:`walking_backwards` is the one cue that does not depend
on labels (docs/fusion.md §5).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import facing_direction
from skelfuse.fusion.mirror import PERMUTATION, choose_labellings
from skelfuse.fusion.settings import FusionSettings

FloatArray = npt.NDArray[np.float64]
Labels = dict[tuple[str, int], bool]
"""Per (sensor id, tracking id): whether that body was mirrored at the last step."""


def label_views(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    sensor_positions: FloatArray,
    keys: Sequence[tuple[str, int]],
    counts: Sequence[int],
    references: Sequence[FloatArray | None],
    reference_facings: FloatArray,
    memories: list[Labels],
    settings: FusionSettings,
) -> tuple[npt.NDArray[np.bool_], FloatArray | None]:
    """Choose every view's labelling, swap the mirrored views in place, remember the choice.

    Args:
        joints: (N, 25, 3) all persons' views, each person's consecutive; metres, world. The
            mirrored ones are swapped back in place.
        states: (N, 25) their tracking states, swapped with them.
        sensor_positions: (N, 3) metres, world (NaN rows: unknown).
        keys: (sensor id, tracking id) of each view.
        counts: views per person.
        references: each person's last fused skeleton (25, 3), or None before its first fusion.
        reference_facings: (P, 3) facing of each person's last skeleton (NaN: unknown).
        memories: each person's labels from the last step; replaced by this step's.
        settings: the mirror term weights, and whether range of motion is wanted too.

    Returns:
        mirrored: (N,) bool.
        rom: (N, 25) range-of-motion factors of each view as labelled, when computed here
            (saves computing them again for the confidence), else None.
    """
    s = settings
    starts = np.cumsum([0, *counts])
    person_of = np.repeat(np.arange(len(counts)), counts)
    previous = np.array([int(memories[p].get(k, -1)) for p, k in zip(person_of, keys, strict=True)])
    mirrored, both_rom = choose_labellings(
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
        need_rom=s.use_range_of_motion,
    )
    for p in range(len(counts)):
        lo, hi = starts[p], starts[p + 1]
        memories[p].clear()
        memories[p].update((k, bool(m)) for k, m in zip(keys[lo:hi], mirrored[lo:hi], strict=True))
    if mirrored.any():
        joints[mirrored] = joints[mirrored][:, PERMUTATION]
        states[mirrored] = states[mirrored][:, PERMUTATION]
    rom = None
    if both_rom is not None:
        rom = both_rom[np.arange(len(joints)), mirrored.astype(np.intp)]
    return mirrored, rom


def walking_backwards(
    joints: FloatArray,
    velocity: FloatArray,
    t_s: float,
    backward_since_s: float | None,
    settings: FusionSettings,
) -> tuple[bool, float | None]:
    """Whether a person has walked backwards long enough to be taken as mirrored as a whole.

    A person born mirrored (every sensor seeing them from the side or behind) stays mirrored,
    since each view is labelled to agree with them and their own facing, reversed, makes the
    back views look like front ones. People walk forwards: walking backwards at
    ``mirror_walk_min_speed_mps`` or more for ``mirror_walk_check_s`` means the labels are wrong.

    Args:
        joints: (25, 3) the person's fused skeleton, metres, world; velocity: (3,) m/s.
        backward_since_s: when the current stretch of walking backwards began, or None.

    Returns:
        (swap now, when the stretch began or None): after a swap the stretch starts over.
    """
    s = settings
    if s.mirror_walk_check_s <= 0 or not s.use_mirror_correction:
        return False, backward_since_s
    speed = float(np.linalg.norm(velocity))
    backwards = False
    if speed >= s.mirror_walk_min_speed_mps:
        facing = facing_direction(joints)
        backwards = bool(np.isfinite(facing).all()) and (
            float(np.dot(facing, velocity)) < -0.5 * speed
        )
    if not backwards:
        return False, None
    if backward_since_s is None:
        return False, t_s
    if t_s - backward_since_s < s.mirror_walk_check_s:
        return False, backward_since_s
    return True, None
