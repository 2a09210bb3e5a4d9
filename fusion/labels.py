"""The mirror-labels step: which views are swapped back, remembered per body, and whole persons
swapped when their anatomy speaks against their labels.

:func:`label_views` asks :func:`scored_labels` for every person's
labelling at once, remembers each (sensor, body)'s decision for the next step's hysteresis, and
swaps the mirrored views in place (:func:`settle`, one compiled loop). Two cues can swap a whole
person whose labels were wrong from its birth: :func:`skelfuse.fusion.mirror.walking_backwards`,
which does not depend on labels (docs/fusion.md §5), and, with ``mirror.redecide``, the anatomy
of all its views (:func:`redecide`), which works standing still too. With
``mirror.unbiased_facing`` the facing the geometry term compares each sensor with is the
person's facing with every sensor's bias of turning the body towards itself taken out
(:func:`unbiased_facings`).

The labels' choice (:func:`scored_labels`, second section) chooses every view's labelling and
measures how much each view's anatomy speaks against it (:func:`view_evidence`), which
``mirror.redecide`` sums per person, in one compiled call (:func:`skelfuse.fusion.mirror.score`).

The unbiased facing (last section): a Kinect turns the body it reports towards itself by
``lean`` × the person's yaw θ to it (clamped to ±90°; the simulator's ``facing_bias``): a view's
own facing is at φ = θ − lean × clamp(θ) from its sensor. A view the sensor mirrored was fitted
to the back, at the apparent yaw θ ∓ 180°, and turned by that; swapped back, its facing is
reversed again. A fused skeleton inherits these turns: a person seen side-on by two sensors
looks turned by 40–60° (the crossing scenario's turns), enough to put a side sensor behind them
and to keep that view's old labels after the sensor flips. Inverting each view's turn under the
labelling chosen, and averaging the unit vectors, gives the facing back. One loop compiled with
numba (:func:`unbiased_loop`): ``%`` as numpy's floating remainder (the divisor's sign), the
sign of 0 as 0, sums over a person's views from 0 view after view, ``atan2`` / ``sin`` / ``cos``
from the C library.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import facing_directions, facing_loop
from skelfuse.fusion.mirror import PERMUTATION, Scored, score
from skelfuse.fusion.mirror_scores import evidence_loop, slots
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
Labels = dict[tuple[str, int], bool]
"""Per (sensor id, tracking id): whether that body was mirrored at the last step."""
VIEW_AGAINST = 0.5
"""A view's evidence against its labels (joints) from which it counts as a view against them
(``mirror.redecide_views``): more than a glitch of one joint at its range-of-motion's edge."""


@dataclass(slots=True)
class LabelDoubt:
    """One person's running evidence against its labels (``mirror.redecide``).

    against: the running sum of evidence (joints, :func:`redecide`); sensors: the sensors that
    saw the person at the last step; born_s, last_s: first and last step seen (seconds);
    facing: (3,) the last step's :func:`unbiased_facings`
    (``mirror.unbiased_facing``; NaN: unknown).
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
            (with ``mirror.redecide`` or ``mirror.unbiased_facing``; None: neither).
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
    unbiased = s.mirror.unbiased_facing and doubts is not None
    if unbiased:
        assert doubts is not None
        reference_facings = _unbiased_references(doubts, reference_facings)
    redeciding = s.mirror.redecide and doubts is not None
    mirrored, both_rom, forward, per_view, summed = scored_labels(
        joints,
        sensor_positions,
        counts,
        references,
        reference_facings,
        previous,
        s,
        need_rom=s.weights.range_of_motion or redeciding,
        want_evidence=redeciding,
    )
    swapped = np.zeros(len(counts), dtype=bool)
    if redeciding and per_view is not None and summed is not None:
        assert doubts is not None
        _redecide_all(mirrored, swapped, (per_view, summed), (keys, starts, person_of),
                      doubts, t_s, s)  # fmt: skip
    _remember(memories, mirrored.tolist(), last, keys, starts)
    facings, rom = settle(
        (joints, states, mirrored),
        (sensor_positions, forward, places.starts, s.weights.view_lean_fraction)
        if unbiased
        else None,
        both_rom if s.weights.range_of_motion or s.mirror.anatomy_weight_m > 0 else None,
    )
    if facings is not None:
        assert doubts is not None
        for doubt, facing in zip(doubts, facings, strict=True):
            doubt.facing = facing
    return mirrored, rom, swapped


def _unbiased_references(doubts: Sequence[LabelDoubt], facings: FloatArray) -> FloatArray:
    """(P, 3) each person's facing of the last step without the sensors' turn towards
    themselves where it is known (its doubt's), else ``facings``' row."""
    remembered = np.array([d.facing for d in doubts], dtype=np.float64)
    known = np.logical_and.reduce(np.isfinite(remembered), axis=1, keepdims=True)
    result: FloatArray = np.where(known, remembered, facings)
    return result


def _redecide_all(
    mirrored: npt.NDArray[np.bool_],
    swapped: npt.NDArray[np.bool_],
    evidence: tuple[FloatArray, FloatArray],
    places: tuple[Sequence[tuple[str, int]], list[int], IntArray],
    doubts: Sequence[LabelDoubt],
    t_s: float,
    s: FusionSettings,
) -> None:
    """Turn over, in place, the labels of each person :func:`redecide` turns over (``mirrored``
    (N,) of its views, ``swapped`` (P,) set), or of the views alone (:func:`views_alone`).

    evidence: (N,) per view and (P,) per person, in joints; places: each view's key, each
    person's first view (then N) and each view's person."""
    per_view, summed = evidence
    keys, starts, person_of = places
    sensors = [frozenset(k[0] for k in keys[lo:hi]) for lo, hi in pairwise(starts)]
    against = summed.tolist()
    turned = False  # whether any person was: most steps none, and no array is asked
    for p, doubt in enumerate(doubts):
        if not redecide(doubt, against[p], sensors[p], t_s, s):
            continue
        swapped[p] = turned = True
        if s.mirror.redecide_views > 1:
            alone = views_alone(per_view[starts[p] : starts[p + 1]], doubt, t_s, s)
            if alone is not None:  # a view or two, not the person: they turn, not the track
                mirrored[starts[p] : starts[p + 1]] ^= alone
                swapped[p] = False
    if turned and swapped.any():
        mirrored ^= swapped[person_of]


def _remember(
    memories: list[Labels],
    flags: list[bool],
    last: list[bool | int],
    keys: Sequence[tuple[str, int]],
    starts: list[int],
) -> None:
    """Each person's memory becomes exactly this step's labels of its views."""
    for p, (lo, hi) in enumerate(pairwise(starts)):
        memory = memories[p]
        if flags[lo:hi] == last[lo:hi] and len(memory) == hi - lo:
            continue  # every view remembered, as decided again, and nothing else: as it is
        memory.clear()
        memory.update(zip(keys[lo:hi], flags[lo:hi], strict=True))


def settle(
    labelled: tuple[FloatArray, npt.NDArray[np.uint8], npt.NDArray[np.bool_]],
    facing_terms: tuple[FloatArray, FloatArray | None, IntArray, float] | None,
    factors: FloatArray | None,
) -> tuple[FloatArray | None, FloatArray | None]:
    """After the choice, in one compiled call: the mirrored views swapped back in place, each
    person's unbiased facing, and each view's range-of-motion factors as labelled.

    Args:
        labelled: joints (N, 25, 3) float64 and states (N, 25) uint8, swapped in place where
            mirrored (N,) bool.
        facing_terms: sensor positions (N, 3), each view's forward axis as reported and swapped
            (N, 2, 3) or None (then taken from the swapped joints), (P + 1,) each person's
            first view then N, and the sensors' lean in [0, 1); None: no facings.
        factors: (N, 2, 25) range-of-motion factors as reported and swapped, or None.

    Returns:
        facings (P, 3) horizontal unit vectors (NaN rows: unknown) and rom (N, 25), each None
        when not asked for.

    Raises:
        ValueError: when the lean is not in [0, 1).
    """
    joints, states, mirrored = labelled
    points, flags = plain(joints), plain(states, np.uint8)
    count = len(points)
    sensors, forward, starts, lean = facing_terms or (np.zeros((count, 3)), None, [0, count], 0.0)
    check_lean(lean)
    facings = np.empty((len(starts) - 1, 3))
    rom = np.empty((count, JOINT_COUNT))
    _settled_loop(
        (points, flags, plain(mirrored, np.bool_), plain(PERMUTATION, np.intp)),
        (plain(sensors), plain(np.zeros((0, 2, 3)) if forward is None else forward),
         plain(starts, np.intp), float(lean)),
        plain(np.zeros((0, 2, JOINT_COUNT)) if factors is None else factors),
        (facing_terms is not None, factors is not None),
        (facings, rom),
    )  # fmt: skip
    if points is not joints:  # not writable in place as they were: copied, now written back
        joints[...] = points
    if flags is not states:
        states[...] = flags
    return facings if facing_terms is not None else None, rom if factors is not None else None


@jit
def _settled_loop(  # one loop for three steps: a call each costs more than their work
    labelled: tuple[FloatArray, npt.NDArray[np.uint8], npt.NDArray[np.bool_], IntArray],
    facing_terms: tuple[FloatArray, FloatArray, IntArray, float],
    factors: FloatArray,
    wanted: tuple[bool, bool],
    out: tuple[FloatArray, FloatArray],
) -> None:
    joints, states, mirrored, permutation = labelled
    sensor_positions, forward, starts, lean = facing_terms
    facings, rom = out
    _swap_loop(joints, states, mirrored, permutation)
    count = joints.shape[0]
    if wanted[1]:
        for v in range(count):
            chosen = 1 if mirrored[v] else 0
            for j in range(joints.shape[1]):
                rom[v, j] = factors[v, chosen, j]
    if not wanted[0]:
        return
    own = np.empty((count, 3))
    if forward.shape[0] == count:  # each view's facing from its chosen labelling's forward axis
        for v in range(count):
            axis = forward[v, 1 if mirrored[v] else 0]
            h0, h1, h2 = axis[0] * 1.0, axis[1] * 0.0, axis[2] * 1.0
            norm = math.sqrt((h0 * h0 + h1 * h1) + h2 * h2)
            finite = math.isfinite(h0) and math.isfinite(h1) and math.isfinite(h2)
            if finite and not norm < 1e-6:
                own[v, 0], own[v, 1], own[v, 2] = h0 / norm, h1 / norm, h2 / norm
            else:
                own[v, 0] = own[v, 1] = own[v, 2] = math.nan
    else:  # from the swapped joints (the same bits)
        facing_loop(joints, own)
    unbiased_loop(joints[:, 0].copy(), sensor_positions, own, mirrored, starts, lean, facings)


@jit
def _swap_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    mirrored: npt.NDArray[np.bool_],
    permutation: IntArray,
) -> None:
    """Swap left and right of the ``mirrored`` (N,) views in place: ``joints`` (N, 25, 3) and
    ``states`` (N, 25) rows reordered by ``permutation`` (25,)."""
    size = len(permutation)
    points = np.empty((size, 3))
    flags = np.empty(size, dtype=np.uint8)
    for v in range(len(mirrored)):
        if not mirrored[v]:
            continue
        for j in range(size):
            points[j, 0], points[j, 1], points[j, 2] = (
                joints[v, j, 0],
                joints[v, j, 1],
                joints[v, j, 2],
            )
            flags[j] = states[v, j]
        for j in range(size):
            k = permutation[j]
            joints[v, j, 0], joints[v, j, 1], joints[v, j, 2] = (
                points[k, 0],
                points[k, 1],
                points[k, 2],
            )
            states[v, j] = flags[k]


def views_alone(
    per_view: FloatArray, doubt: LabelDoubt, t_s: float, s: FusionSettings
) -> npt.NDArray[np.bool_] | None:
    """The views to turn over alone when :func:`redecide` would turn a whole person over, or
    None to turn the person (``mirror.redecide_views``).

    A track mirrored as a whole shows it in every view that sees the legs; when the evidence of
    this step comes from fewer than ``mirror.redecide_views`` views (those with at least
    ``VIEW_AGAINST`` joints against), while the person has more, it is those views whose labels
    are stale, not the track: a sensor near its side flips its labels as the person turns, and
    its view's feet are the least reliable there. Turning the whole person over would make every
    other view wrong until it turns again (the crossing scenario's in-place turns). A young
    person (``mirror.redecide_young_s``; its labels were a guess) and a person with fewer views
    turn over as a whole.

    Args:
        per_view: (S,) this step's :func:`view_evidence` of the person's views, in joints.
        doubt: the person's running evidence (its birth time).
        t_s: the instant, seconds.
    """
    against = per_view >= VIEW_AGAINST
    young = doubt.born_s is not None and t_s - doubt.born_s < s.mirror.redecide_young_s
    if young or len(per_view) < s.mirror.redecide_views:
        return None
    if int(against.sum()) >= s.mirror.redecide_views:
        return None
    result: npt.NDArray[np.bool_] = against
    return result


def redecide(
    doubt: LabelDoubt, evidence: float, sensors: frozenset[str], t_s: float, s: FusionSettings
) -> bool:
    """Whether a person's labels are turned over now; updates its running ``doubt``.

    The evidence of each step (:func:`evidence_against`) is
    summed, decaying with ``mirror.redecide_tau_s``; past ``mirror.redecide_evidence`` the
    person is swapped and the sum starts over. A person younger than
    ``mirror.redecide_young_s`` that a sensor has just joined re-decides on this step's
    evidence alone, against half the threshold: its labels were a guess from fewer views.
    """
    if doubt.born_s is None:
        doubt.born_s = t_s
    dt = 0.0 if doubt.last_s is None else max(t_s - doubt.last_s, 0.0)
    decay = math.exp(-dt / s.mirror.redecide_tau_s) if s.mirror.redecide_tau_s > 0 else 0.0
    joined = bool(sensors - doubt.sensors) and doubt.last_s is not None
    young = t_s - doubt.born_s < s.mirror.redecide_young_s
    doubt.against = max(doubt.against * decay + evidence, 0.0)
    doubt.sensors, doubt.last_s = sensors, t_s
    threshold = s.mirror.redecide_evidence
    if joined and young:
        doubt.against, threshold = max(evidence, 0.0), 0.5 * threshold
    if doubt.against <= threshold:
        return False
    doubt.against = 0.0
    doubt.swaps += 1
    return True


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loops now, for the argument types every
    call passes (:func:`~skelfuse.jit.plain`), so no frame waits for it."""
    views = np.zeros((2, 25, 3))
    labelled = (views, np.zeros((2, 25), np.uint8), np.ones(2, np.bool_))
    for forward in (np.ones((2, 2, 3)), None):
        settle(labelled, (np.ones((2, 3)), forward, np.array([0, 2]), 0.5), np.ones((2, 2, 25)))
    settle(labelled, None, None)
    unbiased_facings(views, np.ones((2, 3)), np.zeros(2, bool), [2], 0.5)


# --- The labels' choice and its anatomical evidence ----------------------------------------------


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


# --- The unbiased facing: each person's facing with every sensor's yaw bias taken out ------------


BoolArray = npt.NDArray[np.bool_]

_PI = math.pi


def unbiased_facings(
    joints: FloatArray,
    sensor_positions: FloatArray,
    mirrored: BoolArray,
    counts: Sequence[int],
    lean: float,
    own: FloatArray | None = None,
) -> FloatArray:
    """(P, 3) each person's horizontal facing from its labelled views, each sensor's yaw bias
    taken out; NaN rows where no view gives one.

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
    check_lean(lean)
    points = plain(joints)
    facings = facing_directions(points) if own is None else plain(own)
    out = np.empty((len(counts), 3))
    unbiased_loop(
        np.ascontiguousarray(points[:, 0]),
        plain(sensor_positions),
        facings,
        plain(mirrored, np.bool_),
        plain(slots(tuple(counts)).starts, np.intp),
        float(lean),
        out,
    )
    return out


def check_lean(lean: float) -> None:
    """Raises ValueError when ``lean`` (a share of the yaw) is not in [0, 1)."""
    if not 0.0 <= lean < 1.0:
        raise ValueError(f"lean must be in [0, 1), got {lean}")


@jit
def _wrap(angle: float) -> float:
    """An angle (radians) wrapped to [−π, π): (angle + π) mod 2π − π."""
    return (angle + _PI) % (2 * _PI) - _PI


@jit
def _sign(x: float) -> float:
    """±1, 0 at ±0, NaN stays NaN (``np.sign``)."""
    if x > 0:
        return 1.0
    if x < 0:
        return -1.0
    if x == 0:
        return 0.0
    return x


@jit
def _unturn(phi: float, lean: float) -> float:
    """The yaw θ whose view is at φ = θ − lean × clamp(θ, ±90°) (monotonic: one θ per φ)."""
    knee = (1.0 - lean) * (_PI / 2)
    if abs(phi) <= knee:
        return phi / (1.0 - lean)
    return phi + lean * (_PI / 2) * _sign(phi)


@jit
def unbiased_loop(
    origins: FloatArray,
    sensor_positions: FloatArray,
    own: FloatArray,
    mirrored: BoolArray,
    starts: IntArray,
    lean: float,
    out: FloatArray,
) -> None:
    """Fill ``out`` (P, 3) with each person's unbiased facing (NaN rows where unknown).

    origins: (N, 3) each view's SpineBase; sensor_positions: (N, 3); own: (N, 3) each view's
    horizontal unit facing as labelled (NaN: unknown); mirrored: (N,) the labelling chosen;
    starts: (P + 1,) each person's first view, then N; lean: in [0, 1).
    """
    for p in range(len(starts) - 1):
        m0 = m1 = m2 = 0.0
        for v in range(starts[p], starts[p + 1]):
            flipped = mirrored[v]
            sensor_angle = math.atan2(
                sensor_positions[v, 0] - origins[v, 0], sensor_positions[v, 2] - origins[v, 2]
            )
            phi = _wrap(sensor_angle - math.atan2(own[v, 0], own[v, 2]))
            if flipped:  # turned at its apparent yaw (facing reversed): invert there, turn back
                phi = _wrap(phi - _PI)
            theta = _unturn(phi, lean)
            if flipped:
                theta = _wrap(theta + _PI)
            angle = sensor_angle - theta
            if math.isfinite(angle):
                m0 += math.sin(angle)
                m1 += 0.0
                m2 += math.cos(angle)
        norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if norm > 1e-6:
            out[p, 0], out[p, 1], out[p, 2] = m0 / norm, m1 / norm, m2 / norm
        else:
            out[p, 0] = out[p, 1] = out[p, 2] = math.nan
