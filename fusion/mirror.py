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

All 2^S combinations are scored at once (S ≤ 10 sensors per person; 3 views: 8 combinations).
Pure functions on arrays; the per-(sensor, body) memory for the hysteresis is kept by
:mod:`skelfuse.fusion.labels`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import facing_direction, rom_factors_and_forward
from skelfuse.fusion.mirror_labellings import (
    COMBOS,
    MAX_VIEWS,
    PAIR_TAKE,
    PAIRS,
    ROWS,
    SCREEN_FROM_VIEWS,
    SWAPS,
    VIEW_TAKE,
    screen,
)
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

PERMUTATION: Final = np.array(MIRROR_PERMUTATION)
LATERAL_JOINTS: Final = np.array([j for j in range(JOINT_COUNT) if MIRROR_PERMUTATION[j] != j])
"""The 20 joints that have a left or right side."""

SWAP_PRIOR_M: Final = 0.01
"""Cost of calling a view mirrored at all: sensors are right more often than not."""

_HORIZONTAL: Final = np.array([1.0, 0.0, 1.0])
_LABELS: Final = np.array([0.0, 1.0])
_NO_LATERAL: Final = np.full((len(LATERAL_JOINTS), 3), np.nan)


def labellings(views: npt.ArrayLike) -> FloatArray:
    """Both labellings of each view: (S, 2, 25, 3), index 1 with left and right swapped."""
    v = np.asarray(views, dtype=np.float64)
    return np.stack([v, v[:, PERMUTATION]], axis=1)


def _mean_lateral_distance(a: FloatArray, b: FloatArray) -> FloatArray:
    """Mean distance over the lateral joints both have; 0 where they share none.

    a, b: broadcastable (..., 20, 3) arrays of the :data:`LATERAL_JOINTS` only. Returns (...).
    """
    diff = a - b
    d = np.sqrt((diff * diff).sum(-1))  # == np.linalg.norm(diff, axis=-1)
    finite = np.isfinite(d)
    count = finite.sum(-1)
    total = np.where(finite, d, 0.0).sum(-1)
    result: FloatArray = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return result


def _mean_distance(a: FloatArray, b: FloatArray) -> FloatArray:
    """Mean distance over the lateral joints both have; 0 where they share none.

    a, b: broadcastable (..., 25, 3) arrays. Returns (...).
    """
    return _mean_lateral_distance(a[..., LATERAL_JOINTS, :], b[..., LATERAL_JOINTS, :])


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
    total = views.shape[0]
    both = np.empty((total, 2, JOINT_COUNT, 3))
    both[:, 0] = views
    both[:, 1] = views[:, PERMUTATION]
    lateral = both[:, :, LATERAL_JOINTS]  # (N, 2, 20, 3)
    starts = np.cumsum([0, *counts])

    factors = anatomy = forward = None
    if anatomy_weight_m > 0 or need_rom:
        flat_factors, flat_forward = rom_factors_and_forward(
            both.reshape(-1, JOINT_COUNT, 3), rom_scale_deg
        )
        factors = flat_factors.reshape(total, 2, JOINT_COUNT)
        forward = flat_forward.reshape(total, 2, 3)
        if anatomy_weight_m > 0:
            anatomy = (1.0 - flat_factors).sum(axis=1).reshape(total, 2)

    # Agreement between views: one row per pair i < j of each person, (K, 2, 2).
    firsts, seconds = [], []
    for p, n in enumerate(counts):
        if n > 1:
            first, second = PAIRS[n]
            firsts.append(first + starts[p])
            seconds.append(second + starts[p])
    pair = None
    if firsts:
        first_all, second_all = np.concatenate(firsts), np.concatenate(seconds)
        pair = _mean_lateral_distance(
            lateral[first_all][:, :, None], lateral[second_all][:, None, :]
        )

    # Where each person stands (mean SpineBase of its views) and the direction to each sensor.
    spine = views[:, 0]
    finite = np.isfinite(spine)
    person_of = np.repeat(np.arange(len(counts)), counts)
    slot_of = np.arange(total) - starts[person_of]
    # Sums per person over a zero-padded (P, S_max, 3) block: the same order as np.nanmean.
    padded = np.zeros((len(counts), max(counts), 2, 3))
    padded[person_of, slot_of, 0] = np.where(finite, spine, 0.0)
    padded[person_of, slot_of, 1] = finite
    sums = padded.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        body = sums[:, 0] / sums[:, 1]
        to_sensor = (sensor_positions - body[person_of]) * _HORIZONTAL
        to_sensor /= np.sqrt((to_sensor * to_sensor).sum(-1, keepdims=True))

    prev = None if previous is None else np.asarray(previous)
    known = None if prev is None else prev >= 0
    pair_start = np.cumsum([0] + [n * (n - 1) // 2 for n in counts])

    # Agreement with the track, every view at once.
    has_ref = [ref is not None for ref in references]
    to_ref = np.zeros((total, 2))
    if any(has_ref):
        ref_lateral = np.stack(
            [_NO_LATERAL if ref is None else ref[LATERAL_JOINTS] for ref in references]
        )
        to_ref = _mean_lateral_distance(lateral, ref_lateral[person_of][:, None])

    # Geometry with a known facing (from the track): a per-view term, (N, 2) for labels 0, 1.
    per_label = np.zeros((total, 2))
    row_geometry = [False] * len(counts)
    for p, ref in enumerate(references):
        if ref is None or reference_facings is None:
            continue
        facing_ref = reference_facings[p]
        if np.isfinite(facing_ref).all():
            lo, hi = starts[p], starts[p + 1]
            # Every labelling sees the same facing, so one row of the (C, S) product is enough
            # (computed as the product of a broadcast facing: matmul's own rounding).
            cos = (np.broadcast_to(facing_ref, (2, 3)) @ to_sensor[lo:hi].T)[0]
            cos = np.where(np.isnan(cos), 0.0, cos)  # np.nan_to_num (cos is finite or NaN)
            per_label[lo:hi, 0] = np.maximum(-cos, 0.0)
            per_label[lo:hi, 1] = np.maximum(cos, 0.0)
            row_geometry[p] = True

    mirrored = np.zeros(total, dtype=bool)
    # Persons with the same number of views and the same kinds of terms are scored together:
    # (G, C) costs, every term summed in the order a single person's would be.
    groups: dict[tuple[int, bool, bool], list[int]] = {}
    for p, n in enumerate(counts):
        groups.setdefault((n, has_ref[p], row_geometry[p]), []).append(p)
    for (n, with_ref, known_facing), members in groups.items():
        combos = COMBOS[n]
        take = VIEW_TAKE[n]
        people = np.array(members)
        views_of = (starts[people][:, None] + np.arange(n)[None, :]).ravel()  # (G·n,)
        size = len(members)

        k = n * (n - 1) // 2
        block = np.zeros((size, 0))
        if k:
            rows_of = (pair_start[people][:, None] + np.arange(k)[None, :]).ravel()
            assert pair is not None
            block = pair[rows_of].reshape(size, 4 * k)
        mine = mine_known = None
        if prev is not None and known is not None:
            mine, mine_known = prev[views_of].reshape(size, n), known[views_of].reshape(size, n)
        tables: list[tuple[float, FloatArray]] = []
        if with_ref:
            tables.append((track_weight, to_ref[views_of].reshape(size, 2 * n)))
        geometry_sum = None
        if known_facing:
            tables.append((geometry_weight_m, per_label[views_of].reshape(size, 2 * n)))
        else:
            geometry_sum = np.stack(
                [
                    _candidate_geometry(
                        combos,
                        both[starts[p] : starts[p + 1]],
                        None if forward is None else forward[starts[p] : starts[p + 1]],
                        to_sensor[starts[p] : starts[p + 1]],
                        rom_scale_deg,
                    ).sum(axis=1)
                    for p in members
                ]
            )
        if anatomy is not None:
            tables.append((anatomy_weight_m, anatomy[views_of].reshape(size, 2 * n)))

        # For many views, one matrix product first estimates every labelling's cost: a person
        # whose best estimate beats all others by more than rounding could ever explain has
        # its labelling (see screen); the others are scored exactly.
        exact = np.arange(size)
        if n >= SCREEN_FROM_VIEWS and geometry_sum is None:
            unary = SWAP_PRIOR_M * np.tile(_LABELS, (size, n))
            for weight, table in tables:
                unary = unary + weight * table
            if mine is not None and mine_known is not None:
                changed = (_LABELS[None, None, :] != mine[:, :, None]) & mine_known[:, :, None]
                unary = unary + hysteresis_m * changed.reshape(size, 2 * n)
            clear = screen(n, block, unary)
            for g in np.flatnonzero(clear >= 0):
                mirrored[views_of[g * n : (g + 1) * n]] = combos[clear[g]].astype(bool)
            exact = np.flatnonzero(clear < 0)
            if not len(exact):
                continue

        # Exact costs of every labelling, (G, C), term by term as for one person alone.
        if k:
            # Agreement between views: Σ over pairs i < j of D[i, j, c_i, c_j], pair by pair.
            cost = block[exact][:, PAIR_TAKE[n]].sum(axis=1)
        else:
            cost = np.zeros((len(exact), len(combos)))
        term = 0
        if with_ref:
            weight, table = tables[term]
            term += 1
            cost += weight * table[exact][:, take].sum(axis=2)
        if geometry_sum is not None:
            cost += geometry_weight_m * geometry_sum[exact]
        else:
            weight, table = tables[term]
            term += 1
            cost += weight * table[exact][:, take].sum(axis=2)
        if anatomy is not None:
            weight, table = tables[term]
            cost += weight * table[exact][:, take].sum(axis=2)
        cost += SWAP_PRIOR_M * SWAPS[n]
        if mine is not None and mine_known is not None:
            changed_all = (combos[None] != mine[exact][:, None, :]) & mine_known[exact][:, None, :]
            cost += hysteresis_m * changed_all.sum(axis=2)
        best = combos[np.argmin(cost, axis=1)]  # (G, n), the first minimum as np.argmin
        for row, g in enumerate(exact):
            mirrored[views_of[g * n : (g + 1) * n]] = best[row].astype(bool)
    return mirrored, factors


def _candidate_geometry(
    combos: IntArray,
    both: FloatArray,
    forward: FloatArray | None,
    to_sensor: FloatArray,
    rom_scale_deg: float,
) -> FloatArray:
    """(C, S) geometry term with the facing taken from each candidate labelling itself.

    The facing of labelling c is the sum of its views' horizontal forward axes.
    """
    n = combos.shape[1]
    if forward is None:
        _, flat_forward = rom_factors_and_forward(both.reshape(-1, JOINT_COUNT, 3), rom_scale_deg)
        forward = flat_forward.reshape(n, 2, 3)
    own = np.nan_to_num(forward * _HORIZONTAL)
    facing = own[ROWS[n], combos].sum(axis=1)  # (C, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        facing = facing / np.linalg.norm(facing, axis=-1, keepdims=True)
    cos = np.nan_to_num(facing @ np.ascontiguousarray(to_sensor).T)  # (C, S)
    geometry: FloatArray = np.where(combos == 0, np.maximum(-cos, 0.0), np.maximum(cos, 0.0))
    return geometry
