"""The mirror-labels step: which views are swapped back, remembered per body, and whole persons
swapped when they walk backwards.

:func:`label_views` asks :func:`skelfuse.fusion.mirror.choose_labellings` for every person's
labelling at once, remembers each (sensor, body)'s decision for the next step's hysteresis, and
swaps the mirrored views in place. Two cues can swap a whole person whose labels were wrong
from its birth: :func:`walking_backwards`, which does not depend on labels (docs/fusion.md §5),
and, with ``mirror_redecide``, the anatomy of all its views (:func:`redecide`), which works
standing still too. With ``mirror_unbiased_facing`` the facing the geometry term compares
each sensor with is the person's facing with every sensor's bias of turning the body towards
itself taken out (:func:`unbiased_facings`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_label_stage, kernels_stages
from skelfuse.fusion.anatomy import HORIZONTAL, facing_direction, facing_directions
from skelfuse.fusion.kernels_jit import in_place
from skelfuse.fusion.label_scores import scored_labels
from skelfuse.fusion.mirror import PERMUTATION
from skelfuse.fusion.mirror_labellings import slots
from skelfuse.fusion.settings import FusionSettings

FloatArray = npt.NDArray[np.float64]
Labels = dict[tuple[str, int], bool]
"""Per (sensor id, tracking id): whether that body was mirrored at the last step."""
VIEW_AGAINST = 0.5
"""A view's evidence against its labels (joints) from which it counts as a view against them
(``mirror_redecide_views``): more than a glitch of one joint at its range-of-motion's edge."""


@dataclass(slots=True)
class LabelDoubt:
    """One person's running evidence against its labels (``mirror_redecide``).

    against: the running sum of evidence (joints, :func:`redecide`); sensors: the sensors that
    saw the person at the last step; born_s, last_s: first and last step seen (seconds);
    facing: (3,) the last step's :func:`unbiased_facings` (``mirror_unbiased_facing``; NaN:
    unknown).
    """

    against: float = 0.0
    sensors: frozenset[str] = field(default_factory=frozenset)
    born_s: float | None = None
    last_s: float | None = None
    swaps: int = 0
    """How often the person was swapped whole by this cue (diagnostics, tests)."""
    facing: FloatArray = field(default_factory=lambda: np.full(3, np.nan))


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
    doubts: Sequence[LabelDoubt] | None = None,
    t_s: float = 0.0,
) -> tuple[npt.NDArray[np.bool_], FloatArray | None, npt.NDArray[np.bool_]]:
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
        doubts: each person's evidence against its labels and unbiased facing, updated here
            (with ``mirror_redecide`` or ``mirror_unbiased_facing``; None: neither).
        t_s: the instant, seconds (for the running evidence).

    Returns:
        mirrored: (N,) bool.
        rom: (N, 25) range-of-motion factors of each view as labelled, when computed here
            (saves computing them again for the confidence), else None.
        swapped: (P,) bool, the persons whose every view's labelling was turned over by
            :func:`redecide` (the caller swaps their track, filter and bone samples).
    """
    s = settings
    places = slots(tuple(counts))
    person_of = places.person_of
    starts = places.starts.tolist()
    last: list[bool | int] = [
        memories[p].get(k, -1) for p, k in zip(person_of.tolist(), keys, strict=True)
    ]
    previous = np.array(last, dtype=np.intp)  # 1, 0, or −1 (unknown)
    unbiased = s.mirror_unbiased_facing and doubts is not None
    if unbiased:  # the last step's facing without the sensors' turn, where known
        assert doubts is not None
        remembered = np.array([d.facing for d in doubts], dtype=np.float64)
        known = np.logical_and.reduce(np.isfinite(remembered), axis=1, keepdims=True)
        reference_facings = np.where(known, remembered, reference_facings)
    redeciding = s.mirror_redecide and doubts is not None
    mirrored, both_rom, forward, per_view, summed = scored_labels(
        joints,
        sensor_positions,
        counts,
        references,
        reference_facings,
        previous,
        s,
        need_rom=s.use_range_of_motion or redeciding,
        want_evidence=redeciding,
    )
    swapped = np.zeros(len(counts), dtype=bool)
    if redeciding and per_view is not None and summed is not None:
        assert doubts is not None
        sensors = [frozenset(k[0] for k in keys[lo:hi]) for lo, hi in pairwise(starts)]
        evidence = summed.tolist()
        turned = False  # whether any person was: most steps none, and no array is asked
        for p, doubt in enumerate(doubts):
            if not redecide(doubt, evidence[p], sensors[p], t_s, s):
                continue
            swapped[p] = turned = True
            if s.mirror_redecide_views > 1:
                alone = views_alone(per_view[starts[p] : starts[p + 1]], doubt, t_s, s)
                if alone is not None:  # a view or two, not the person: they turn, not the track
                    mirrored[starts[p] : starts[p + 1]] ^= alone
                    swapped[p] = False
        if turned and swapped.any():
            mirrored ^= swapped[person_of]
    flags = mirrored.tolist()
    for p, (lo, hi) in enumerate(pairwise(starts)):
        memory = memories[p]
        if flags[lo:hi] == last[lo:hi] and len(memory) == hi - lo:
            continue  # every view remembered, as decided again, and nothing else: as it is
        memory.clear()
        memory.update(zip(keys[lo:hi], flags[lo:hi], strict=True))
    if (
        unbiased
        and forward is not None
        and both_rom is not None
        and (s.use_range_of_motion or s.mirror_anatomy_weight_m > 0)
        and 0.0 <= s.view_lean_fraction < 1.0
        and kernels.enabled()
        and kernels_label_stage.warmed()
        and in_place(joints, np.float64)
        and in_place(states, np.uint8)
    ):  # the usual step: the swap, the facings and the factors as labelled in one call
        assert doubts is not None
        facings, as_labelled = kernels_label_stage.settled(
            joints, states, mirrored, PERMUTATION,
            (sensor_positions, forward, places.starts, s.view_lean_fraction), both_rom,
        )  # fmt: skip
        for doubt, facing in zip(doubts, facings, strict=True):
            doubt.facing = facing
        return mirrored, as_labelled, swapped
    swapped_here = kernels.enabled() and kernels_stages.swap_mirrored(
        joints, states, mirrored, PERMUTATION
    )
    if mirrored.any() and not swapped_here:
        joints[mirrored] = joints[mirrored][:, PERMUTATION]
        states[mirrored] = states[mirrored][:, PERMUTATION]
    if unbiased:
        assert doubts is not None
        # Each view's facing as labelled: the forward axis of its chosen labelling, already
        # computed for the range of motion (the same bits as from the swapped joints).
        if forward is not None and kernels.enabled() and 0.0 <= s.view_lean_fraction < 1.0:
            facings = kernels_stages.unbiased_facings(
                joints[:, 0], sensor_positions, forward, mirrored, places.starts,
                s.view_lean_fraction,
            )  # fmt: skip
        else:
            own = None
            if forward is not None:
                chosen = forward[np.arange(len(joints)), mirrored.view(np.uint8)]
                own = _facings_of_forward(chosen)
            facings = unbiased_facings(
                joints, sensor_positions, mirrored, counts, s.view_lean_fraction, own
            )
        for doubt, facing in zip(doubts, facings, strict=True):
            doubt.facing = facing
    rom = None
    if both_rom is not None and (s.use_range_of_motion or s.mirror_anatomy_weight_m > 0):
        rom = both_rom[np.arange(len(joints)), mirrored.astype(np.intp)]
    return mirrored, rom, swapped


def views_alone(
    per_view: FloatArray, doubt: LabelDoubt, t_s: float, s: FusionSettings
) -> npt.NDArray[np.bool_] | None:
    """The views to turn over alone when :func:`redecide` would turn a whole person over, or
    None to turn the person (``mirror_redecide_views``).

    A track mirrored as a whole shows it in every view that sees the legs; when the evidence of
    this step comes from fewer than ``mirror_redecide_views`` views (those with at least
    ``VIEW_AGAINST`` joints against), while the person has more, it is those views whose labels
    are stale, not the track: a sensor near its side flips its labels as the person turns, and
    its view's feet are the least reliable there. Turning the whole person over would make every
    other view wrong until it turns again (the crossing scenario's in-place turns). A young
    person (``mirror_redecide_young_s``; its labels were a guess) and a person with fewer views
    turn over as a whole.

    Args:
        per_view: (S,) this step's :func:`view_evidence` of the person's views, in joints.
        doubt: the person's running evidence (its birth time).
        t_s: the instant, seconds.
    """
    against = per_view >= VIEW_AGAINST
    young = doubt.born_s is not None and t_s - doubt.born_s < s.mirror_redecide_young_s
    if young or len(per_view) < s.mirror_redecide_views:
        return None
    if int(against.sum()) >= s.mirror_redecide_views:
        return None
    result: npt.NDArray[np.bool_] = against
    return result


def redecide(
    doubt: LabelDoubt, evidence: float, sensors: frozenset[str], t_s: float, s: FusionSettings
) -> bool:
    """Whether a person's labels are turned over now; updates its running ``doubt``.

    The evidence of each step (:func:`~skelfuse.fusion.label_scores.evidence_against`) is
    summed, decaying with ``mirror_redecide_tau_s``; past ``mirror_redecide_evidence`` the
    person is swapped and the sum starts over. A person younger than
    ``mirror_redecide_young_s`` that a sensor has just joined re-decides on this step's
    evidence alone, against half the threshold: its labels were a guess from fewer views.
    """
    if doubt.born_s is None:
        doubt.born_s = t_s
    dt = 0.0 if doubt.last_s is None else max(t_s - doubt.last_s, 0.0)
    decay = math.exp(-dt / s.mirror_redecide_tau_s) if s.mirror_redecide_tau_s > 0 else 0.0
    joined = bool(sensors - doubt.sensors) and doubt.last_s is not None
    young = t_s - doubt.born_s < s.mirror_redecide_young_s
    doubt.against = max(doubt.against * decay + evidence, 0.0)
    doubt.sensors, doubt.last_s = sensors, t_s
    threshold = s.mirror_redecide_evidence
    if joined and young:
        doubt.against, threshold = max(evidence, 0.0), 0.5 * threshold
    if doubt.against <= threshold:
        return False
    doubt.against = 0.0
    doubt.swaps += 1
    return True


def walking_backwards(
    joints: FloatArray,
    velocity: FloatArray,
    t_s: float,
    backward_since_s: float | None,
    settings: FusionSettings,
    facing: FloatArray | None = None,
) -> tuple[bool, float | None]:
    """Whether a person has walked backwards long enough to be taken as mirrored as a whole.

    A person born mirrored (every sensor seeing them from the side or behind) stays mirrored,
    since each view is labelled to agree with them and their own facing, reversed, makes the
    back views look like front ones. People walk forwards: walking backwards at
    ``mirror_walk_min_speed_mps`` or more for ``mirror_walk_check_s`` means the labels are wrong.

    Args:
        joints: (25, 3) the person's fused skeleton, metres, world; velocity: (3,) m/s.
        backward_since_s: when the current stretch of walking backwards began, or None.
        facing: the skeleton's ``facing_direction`` (3,) if the caller has it (one batched
            call for every person is cheaper); None: worked out here when needed.

    Returns:
        (swap now, when the stretch began or None): after a swap the stretch starts over.
    """
    s = settings
    if s.mirror_walk_check_s <= 0 or not s.use_mirror_correction:
        return False, backward_since_s
    # On Python floats: the operations np.linalg.norm and np.dot do on three components, in
    # their order ((a₀b₀ + a₁b₁) + a₂b₂), without a numpy call's cost.
    v0, v1, v2 = np.asarray(velocity, dtype=np.float64).tolist()
    speed = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    backwards = False
    if speed >= s.mirror_walk_min_speed_mps:
        if facing is None:
            facing = facing_direction(joints)
        f0, f1, f2 = np.asarray(facing, dtype=np.float64).tolist()
        finite = math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)
        backwards = finite and f0 * v0 + f1 * v1 + f2 * v2 < -0.5 * speed
    if not backwards:
        return False, None
    if backward_since_s is None:
        return False, t_s
    if t_s - backward_since_s < s.mirror_walk_check_s:
        return False, backward_since_s
    return True, None


def unbiased_facings(
    joints: FloatArray,
    sensor_positions: FloatArray,
    mirrored: npt.NDArray[np.bool_],
    counts: Sequence[int],
    lean: float,
    own: FloatArray | None = None,
) -> FloatArray:
    """(P, 3) each person's horizontal facing from its labelled views, each sensor's yaw bias
    taken out (``mirror_unbiased_facing``); NaN rows where no view gives one.

    A Kinect turns the body it reports towards itself by ``lean`` × the person's yaw θ to it
    (clamped to ±90°; the simulator's ``facing_bias``): a view's own facing is at φ = θ − lean ×
    clamp(θ) from its sensor. A view the sensor mirrored was fitted to the back, at the apparent
    yaw θ ∓ 180°, and turned by that; swapped back, its facing is reversed again. A fused
    skeleton inherits these turns: a person seen side-on by two sensors looks turned by
    40–60° (the crossing scenario's turns), enough to put a side sensor behind them and to
    keep that view's old labels after the sensor flips. Inverting each view's turn under the
    labelling chosen, and averaging the unit vectors, gives the facing back.

    Args:
        joints: (N, 25, 3) every person's views, labels corrected; metres, world.
        sensor_positions: (N, 3) metres, world (NaN rows: unknown).
        mirrored: (N,) whether each view was swapped back (the sensor reported it mirrored).
        counts: views per person.
        lean: the share of its yaw a sensor turns a body towards itself, in [0, 1).
        own: (N, 3) each view's :func:`~skelfuse.fusion.anatomy.facing_directions` as
            labelled, when the caller has them (None: computed here).

    Returns:
        (P, 3) horizontal unit vectors (y = 0), NaN where unknown.

    Raises:
        ValueError: when ``lean`` is not in [0, 1).
    """
    if not 0.0 <= lean < 1.0:
        raise ValueError(f"lean must be in [0, 1), got {lean}")
    if own is None:
        own = facing_directions(joints)  # (N, 3), the view's facing as labelled
    to_sensor = sensor_positions - joints[:, 0]
    sensor_angle = np.arctan2(to_sensor[:, 0], to_sensor[:, 2])
    phi = _wrap(sensor_angle - np.arctan2(own[:, 0], own[:, 2]))
    flipped = mirrored.astype(bool)
    if flipped.any():
        # A mirrored view was turned at its apparent yaw (facing reversed): invert there, turn
        # back.
        theta = _unturn(np.where(flipped, _wrap(phi - np.pi), phi), lean)
        theta = np.where(flipped, _wrap(theta + np.pi), theta)
    else:
        theta = _unturn(phi, lean)
    facing_angle = sensor_angle - theta
    vectors = np.zeros((len(facing_angle), 3))
    vectors[:, 0] = np.sin(facing_angle)
    vectors[:, 2] = np.cos(facing_angle)
    usable = np.isfinite(facing_angle)  # sin and cos are finite where the angle is
    # Per person, the sum of its usable views' vectors, row by row as vectors[rows].sum(axis=0)
    # (a zero-padded (P, S_max, 3) block: adding the zeros changes no bit).
    places = slots(tuple(counts))
    padded = np.zeros((len(counts), places.widest, 3))
    padded[places.person_of, places.slot_of] = np.where(usable[:, None], vectors, 0.0)
    mean = padded.sum(axis=1)
    # np.vecdot is the dot product np.linalg.norm uses on one vector (the same bits).
    norm: FloatArray = np.sqrt(np.vecdot(mean, mean))[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        out: FloatArray = np.where(norm > 1e-6, mean / norm, np.nan)
    return out


def _wrap(angle: FloatArray) -> FloatArray:
    """Angles (radians) wrapped to [−π, π)."""
    wrapped: FloatArray = (angle + np.pi) % (2 * np.pi) - np.pi
    return wrapped


def _unturn(phi: FloatArray, lean: float) -> FloatArray:
    """The yaw θ whose view is at φ = θ − lean × clamp(θ, ±90°) (monotonic, so one θ per φ)."""
    knee = (1.0 - lean) * (np.pi / 2)
    theta: FloatArray = np.where(
        np.abs(phi) <= knee, phi / (1.0 - lean), phi + lean * (np.pi / 2) * np.sign(phi)
    )
    return theta


def _facings_of_forward(forward: FloatArray) -> FloatArray:
    """Horizontal unit facings (P, 3) from :func:`body_frame` forward axes (P, 3); NaN rows
    where unknown (the body's forward axis close to vertical, or missing)."""
    horizontal = forward * HORIZONTAL
    # np.vecdot is the dot product np.linalg.norm uses on one vector (the same bits).
    norm = np.sqrt(np.vecdot(horizontal, horizontal))
    ok = np.isfinite(horizontal).all(-1) & ~(norm < 1e-6)
    with np.errstate(invalid="ignore", divide="ignore"):
        result: FloatArray = np.where(ok[:, None], horizontal / norm[:, None], np.nan)
    return result
