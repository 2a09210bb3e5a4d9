"""Mirrored views: detect a view whose left and right labels are swapped, before fusion.

A Kinect v2 assumes the person faces it. Seen from behind, it fits a front-facing body to the
person's back and reports it with left and right swapped, still Tracked, so tracking-state
weights cannot see it (docs/benchmarks.md, first version). Every view of one person therefore
gets a labelling, as reported (0) or swapped back with :data:`MIRROR_PERMUTATION` (1), chosen
jointly for all of the person's views by minimising

- **agreement between views**: Σ over pairs of the mean distance between their left/right joints
  under the two labellings (metres);
- **agreement with the track**: ``track_weight`` × the mean distance of each labelled view to the
  person's previous fused skeleton (when the person already has one): a sensor that flips its
  labels as the person turns away is caught by the jump;
- **geometry**: where the person faces (from the track, or from the candidate labelling itself
  at birth) against the direction to each sensor: a view kept as reported while its sensor is
  behind the person costs ``geometry_weight × (−cos θ)``, a view swapped while its sensor is in
  front ``geometry_weight × cos θ``. This also breaks the tie that pairwise agreement leaves
  (swapping every view agrees as well as swapping none) only when the person faces one sensor
  more than the others;
- **anatomy**: ``anatomy_weight_m`` × Σ over joints of (1 − the range-of-motion factor) of each
  labelled view: with left and right swapped, the body's forward axis is reversed, so bent knees
  look hyperextended and feet point backwards. This is what settles the labelling of a new
  person and of a person all sensors see from behind. It assumes, as the simulator does, that
  a sensor seeing the back reports where the knees and feet really are, only with swapped
  labels (the depth image shows them; the body-part classifier gets the side wrong);
- **hysteresis**: ``hysteresis`` for changing a view's labelling from the previous step, and a
  small prior for reporting a view as mirrored at all.

All 2^S combinations are scored (S ≤ 10 sensors per person; 3 views: 8 combinations), every
person in one compiled call (:func:`score`, the loops in :mod:`skelfuse.fusion.mirror_scores`).
Pure functions on arrays; the per-(sensor, body) memory for the hysteresis is kept by
:mod:`skelfuse.fusion.labels`.

The walking check (last section): a person born mirrored (every sensor seeing them from the side
or behind) stays mirrored, since each view is labelled to agree with them and their own facing,
reversed, makes the back views look like front ones. People walk forwards (docs/fusion.md §5),
so a person who walks backwards for long is taken as mirrored as a whole. The check for every
person at once is one loop compiled with numba (:func:`walking_backwards_now`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import ANGLE_LIMITS, facing_direction
from skelfuse.fusion.mirror_scores import (
    LATERAL_JOINTS,
    LATERAL_SWAP,
    MAX_VIEWS,
    SCREEN_FROM_VIEWS,
    SCREEN_MARGIN_M,
    layout,
    scored_loop,
)
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

PERMUTATION: Final = np.array(MIRROR_PERMUTATION)

SWAP_PRIOR_M: Final = 0.01
"""Cost of calling a view mirrored at all: sensors are right more often than not."""


def labellings(views: npt.ArrayLike) -> FloatArray:
    """Both labellings of each view: (S, 2, 25, 3), index 1 with left and right swapped."""
    v = np.asarray(views, dtype=np.float64)
    return np.stack([v, v[:, PERMUTATION]], axis=1)


def choose_labelling(
    views: npt.ArrayLike,
    sensor_positions: npt.ArrayLike,
    reference: npt.ArrayLike | None = None,
    previous: npt.ArrayLike | None = None,
    *,
    geometry_weight_m: float = 0.15,
    hysteresis_m: float = 0.05,
    track_weight: float = 1.0,
    anatomy_weight_m: float = 0.1,
    rom_scale_deg: float = 15.0,
) -> npt.NDArray[np.bool_]:
    """Which views of one person are mirrored.

    Args:
        views: (S, 25, 3) one person's views, metres, world frame, NaN where unknown.
        sensor_positions: (S, 3) where each view's sensor stands (NaN rows: unknown).
        reference: (25, 3) the person's previous fused skeleton, or None for a new person.
        previous: (S,) previous decision per view: 1 mirrored, 0 not, −1 (or None) unknown.
        geometry_weight_m, hysteresis_m, track_weight, anatomy_weight_m: see the module
            docstring; ``rom_scale_deg`` as in :func:`range_of_motion_factors`.

    Returns:
        (S,) bool, True where the view should be swapped back before fusion.

    Raises:
        ValueError: on more than :data:`MAX_VIEWS` views or mismatched shapes.
    """
    v = np.asarray(views, dtype=np.float64)
    n = v.shape[0]
    if n == 0:
        return np.zeros(0, dtype=bool)
    if n > MAX_VIEWS or v.shape[1:] != (JOINT_COUNT, 3):
        raise ValueError(f"expected (S ≤ {MAX_VIEWS}, 25, 3) views, got {v.shape}")
    sensors = np.asarray(sensor_positions, dtype=np.float64).reshape(n, 3)
    ref = None if reference is None else np.asarray(reference, dtype=np.float64)
    prev = None if previous is None else np.asarray(previous).reshape(n)
    facing = None if ref is None else facing_direction(ref)
    mirrored, _ = choose_labellings(
        v,
        sensors,
        [n],
        [ref],
        None if facing is None else facing[None],
        prev,
        geometry_weight_m=geometry_weight_m,
        hysteresis_m=hysteresis_m,
        track_weight=track_weight,
        anatomy_weight_m=anatomy_weight_m,
        rom_scale_deg=rom_scale_deg,
    )
    return mirrored


def choose_labellings(
    views: FloatArray,
    sensor_positions: FloatArray,
    counts: Sequence[int],
    references: Sequence[FloatArray | None],
    reference_facings: FloatArray | None,
    previous: npt.ArrayLike | None,
    *,
    geometry_weight_m: float,
    hysteresis_m: float,
    track_weight: float,
    anatomy_weight_m: float,
    rom_scale_deg: float,
    need_rom: bool = False,
) -> tuple[npt.NDArray[np.bool_], FloatArray | None]:
    """:func:`choose_labelling` for several persons at once (every per-view term in one pass).

    Args:
        views: (N, 25, 3) the views of all persons, each person's views consecutive.
        sensor_positions: (N, 3).
        counts: views per person (1 … :data:`MAX_VIEWS` each, summing to N).
        references: per person, its previous fused skeleton (25, 3) or None.
        reference_facings: (P, 3) :func:`facing_direction` of each reference (rows of persons
            without one are ignored), or None when no person has a reference.
        previous: (N,) previous decisions (1, 0, −1 unknown), or None.
        need_rom: also return the range-of-motion factors of both labellings.

    Returns:
        mirrored: (N,) bool, as :func:`choose_labelling` per person.
        factors: (N, 2, 25) range-of-motion factors (:func:`range_of_motion_factors`) of each
            view as reported (0) and swapped (1), when computed (anatomy term or ``need_rom``).
    """
    mirrored, factors, _ = choose_labellings_and_forward(
        views,
        sensor_positions,
        counts,
        references,
        reference_facings,
        previous,
        geometry_weight_m=geometry_weight_m,
        hysteresis_m=hysteresis_m,
        track_weight=track_weight,
        anatomy_weight_m=anatomy_weight_m,
        rom_scale_deg=rom_scale_deg,
        need_rom=need_rom,
    )
    return mirrored, factors


def choose_labellings_and_forward(
    views: FloatArray,
    sensor_positions: FloatArray,
    counts: Sequence[int],
    references: Sequence[FloatArray | None],
    reference_facings: FloatArray | None,
    previous: npt.ArrayLike | None,
    *,
    geometry_weight_m: float,
    hysteresis_m: float,
    track_weight: float,
    anatomy_weight_m: float,
    rom_scale_deg: float,
    need_rom: bool = False,
) -> tuple[npt.NDArray[np.bool_], FloatArray | None, FloatArray | None]:
    """:func:`choose_labellings`, and the body's forward axes it computed on the way.

    Returns:
        mirrored, factors: as :func:`choose_labellings`;
        forward: (N, 2, 3) :func:`~skelfuse.fusion.anatomy.body_axes` forward axis of each view
            as reported (0) and swapped (1), when the factors were computed, else None.
    """
    scored = score(
        views,
        sensor_positions,
        counts,
        (references, reference_facings, None if previous is None else np.asarray(previous)),
        (track_weight, geometry_weight_m, anatomy_weight_m, hysteresis_m, rom_scale_deg),
        need_rom=need_rom,
        want_evidence=False,
    )
    return scored.mirrored, scored.factors, scored.forward


class Scored(NamedTuple):
    """Every view's labelling and what was measured on the way (N views, P persons).

    mirrored: (N,) bool, the labelling chosen; factors: (N, 2, 25) range-of-motion factors of
    each view as reported (0) and swapped (1); forward: (N, 2, 3) each labelling's body
    forward axis; per_view: (N,) each view's evidence against its labelling, in joints;
    evidence: (P,) its sum per person. (``factors``, ``forward``, ``per_view`` and ``evidence``
    None where not asked for.)
    """

    mirrored: npt.NDArray[np.bool_]
    factors: FloatArray | None
    forward: FloatArray | None
    per_view: FloatArray | None
    evidence: FloatArray | None


def score(
    views: FloatArray,
    sensor_positions: FloatArray,
    counts: Sequence[int],
    known: tuple[Sequence[FloatArray | None], FloatArray | None, npt.NDArray[np.intp] | None],
    weights: tuple[float, float, float, float, float],
    need_rom: bool,
    want_evidence: bool,
) -> Scored:
    """Every person's labelling in one compiled call (:func:`~skelfuse.fusion.mirror_scores.
    scored_loop`), and each view's evidence against it when ``want_evidence``.

    Args:
        views: (N, 25, 3) metres, world, each person's consecutive; sensor_positions: (N, 3).
        counts: views per person (P, each 1 … :data:`MAX_VIEWS`).
        known: each person's last skeleton (25, 3) or None, the (P, 3) facings of those (NaN:
            unknown) or None, and (N,) each view's last decision (1, 0, −1 unknown) or None.
        weights: the track, geometry and anatomy weights, the hysteresis (metres) and the
            range-of-motion scale (degrees).
        need_rom: return the factors and forward axes even without the anatomy term.
        want_evidence: return the evidence (it comes with the factors).
    """
    references, reference_facings, previous = known
    track, geometry, anatomy, hysteresis, scale_deg = weights
    lay = layout(tuple(counts))
    persons, total = len(counts), len(views)
    kinds = np.zeros((persons, 2), dtype=np.bool_)
    kinds[:, 0] = [ref is not None for ref in references]
    stacked = np.full((persons, JOINT_COUNT, 3), np.nan)
    if kinds[:, 0].any():
        stacked[kinds[:, 0]] = [ref for ref in references if ref is not None]
    facings = np.full((persons, 3), np.nan)
    if reference_facings is not None:
        facings = np.asarray(reference_facings, dtype=np.float64)
        kinds[:, 1] = kinds[:, 0] & np.isfinite(facings).all(axis=1)
    out = (
        np.zeros(total, dtype=np.bool_), np.ones((total, 2, JOINT_COUNT)),
        np.empty((total, 2, 3)), np.empty(total), np.empty(persons),
    )  # fmt: skip
    scored_loop(
        plain(views),
        plain(sensor_positions),
        (plain(lay.starts, np.intp), plain(lay.person_of, np.intp),
         plain(lay.first, np.intp), plain(lay.second, np.intp)),
        (kinds, plain(facings), stacked,
         plain(np.full(total, -1) if previous is None else previous, np.intp)),
        (float(track), float(geometry), float(anatomy) if anatomy > 0 else 0.0,
         SWAP_PRIOR_M, float(hysteresis), 0.0 if previous is None else 1.0),
        (plain(LATERAL_JOINTS, np.intp), plain(LATERAL_SWAP, np.intp), plain(PERMUTATION, np.intp)),
        (SCREEN_FROM_VIEWS, SCREEN_MARGIN_M, float(scale_deg), *ANGLE_LIMITS),
        out,
    )  # fmt: skip
    mirrored, factors, forward, per_view, evidence = out
    if not (need_rom or anatomy > 0):
        return Scored(mirrored, None, None, None, None)
    if not want_evidence:
        return Scored(mirrored, factors, forward, None, None)
    return Scored(mirrored, factors, forward, per_view, evidence)


def warm_up() -> None:
    """Compile (or load from numba's cache) the scoring and walking loops now, for the argument
    types every call passes (:func:`~skelfuse.jit.plain`), so no frame waits for it."""
    views = np.zeros((2, 25, 3))
    for references in ([views[0]], [None]):
        score(views, np.ones((2, 3)), [2], (references, np.ones((1, 3)), np.zeros(2, np.intp)),
              (1.0, 0.15, 0.1, 0.05, 15.0), need_rom=True, want_evidence=True)  # fmt: skip
    walking_backwards_now(np.ones((2, 3)), np.ones((2, 3)), 0.3)


# --- The walking check: a person who walks backwards for long is mirrored as a whole -------------


def walking_backwards(
    joints: FloatArray,
    velocity: FloatArray,
    t_s: float,
    backward_since_s: float | None,
    settings: FusionSettings,
    facing: FloatArray | None = None,
) -> tuple[bool, float | None]:
    """Whether a person has walked backwards long enough to be taken as mirrored as a whole:
    at ``mirror.walk_min_speed_mps`` or more for ``mirror.walk_check_s``.

    Args:
        joints: (25, 3) the person's fused skeleton, metres, world; velocity: (3,) m/s.
        backward_since_s: when the current stretch of walking backwards began, or None.
        facing: the skeleton's ``facing_direction`` (3,) if the caller has it (one batched
            call for every person is cheaper); None: worked out here.

    Returns:
        (swap now, when the stretch began or None): after a swap the stretch starts over.
    """
    s = settings
    if s.mirror.walk_check_s <= 0 or not s.mirror.enabled:
        return False, backward_since_s
    if facing is None:
        facing = facing_direction(joints)
    velocities = np.asarray(velocity, dtype=np.float64).reshape(1, 3)
    facings = np.asarray(facing, dtype=np.float64).reshape(1, 3)
    if not walking_backwards_now(velocities, facings, s.mirror.walk_min_speed_mps)[0]:
        return False, None
    if backward_since_s is None:
        return False, t_s
    if t_s - backward_since_s < s.mirror.walk_check_s:
        return False, backward_since_s
    return True, None


def walking_backwards_now(
    velocities: FloatArray, facings: FloatArray, min_speed: float
) -> npt.NDArray[np.bool_]:
    """(P,) whether each of P persons walks backwards now, before :func:`walking_backwards`'s
    timing: at least ``min_speed`` (m/s) with a finite facing against the velocity by more than
    half the speed. velocities, facings: (P, 3), m/s and unit vectors, world frame."""
    out = np.empty(len(velocities), dtype=np.bool_)
    _backwards_loop(plain(velocities), plain(facings), float(min_speed), out)
    return out


@jit
def _backwards_loop(
    velocities: FloatArray, facings: FloatArray, min_speed: float, out: npt.NDArray[np.bool_]
) -> None:
    """Fill ``out`` (P,) for :func:`walking_backwards_now` (``np.linalg.norm`` and ``np.dot``
    of three components as (a₀b₀ + a₁b₁) + a₂b₂)."""
    for p in range(len(out)):
        v0, v1, v2 = velocities[p, 0], velocities[p, 1], velocities[p, 2]
        speed = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        backwards = False
        if speed >= min_speed:
            f0, f1, f2 = facings[p, 0], facings[p, 1], facings[p, 2]
            finite = math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)
            backwards = finite and f0 * v0 + f1 * v1 + f2 * v2 < -0.5 * speed
        out[p] = backwards
