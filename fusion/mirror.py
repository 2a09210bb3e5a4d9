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

from skelfuse.fusion import kernels, kernels_stages
from skelfuse.fusion.anatomy import facing_direction, rom_factors_and_forward
from skelfuse.fusion.mirror_distances import LATERAL_JOINTS, LATERAL_SWAP, lateral_terms
from skelfuse.fusion.mirror_labellings import (
    COMBOS,
    MAX_VIEWS,
    PAIR_TAKE,
    ROWS,
    SCREEN_FROM_VIEWS,
    SCREEN_MARGIN_M,
    SWAPS,
    VIEW_TAKE,
    layout,
    screen,
)
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

PERMUTATION: Final = np.array(MIRROR_PERMUTATION)

SWAP_PRIOR_M: Final = 0.01
"""Cost of calling a view mirrored at all: sensors are right more often than not."""

_HORIZONTAL: Final = np.array([1.0, 0.0, 1.0])
_LABELS: Final = np.array([0.0, 1.0])


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
    total = views.shape[0]
    both = np.empty((total, 2, JOINT_COUNT, 3))
    both[:, 0] = views
    both[:, 1] = views.take(PERMUTATION, axis=1)  # the fancy index's values, cheaper
    has_ref = [ref is not None for ref in references]
    # Geometry with a known facing (from the track): persons with a reference and a facing.
    geometric = np.zeros(len(counts), dtype=bool)
    if reference_facings is not None:
        geometric = np.array(has_ref) & np.isfinite(reference_facings).all(axis=1)
    lay = layout(tuple(counts), tuple(zip(has_ref, geometric.tolist(), strict=True)))
    person_of = lay.person_of

    factors = anatomy = forward = None
    if anatomy_weight_m > 0 or need_rom:
        flat_factors, flat_forward = rom_factors_and_forward(
            both.reshape(-1, JOINT_COUNT, 3), rom_scale_deg
        )
        factors = flat_factors.reshape(total, 2, JOINT_COUNT)
        forward = flat_forward.reshape(total, 2, 3)

    prev = None if previous is None else np.asarray(previous)
    if kernels.enabled() and len(counts) and geometric.all():  # every facing known: compiled
        assert reference_facings is not None  # (geometric: every person has a facing)
        mirrored = kernels_stages.mirror_scores(
            views,
            sensor_positions,
            (lay.starts, person_of, lay.first, lay.second),
            reference_facings,
            np.array([ref for ref in references if ref is not None], dtype=np.float64),
            factors if anatomy_weight_m > 0 else None,
            prev,
            (track_weight, geometry_weight_m, anatomy_weight_m, SWAP_PRIOR_M, hysteresis_m),
            (LATERAL_JOINTS, LATERAL_SWAP),
            (SCREEN_FROM_VIEWS, SCREEN_MARGIN_M),
        )
        return mirrored, factors, forward
    if factors is not None and anatomy_weight_m > 0:
        anatomy = (1.0 - factors.reshape(-1, JOINT_COUNT)).sum(axis=1).reshape(total, 2)

    # Agreement between views (K, 2, 2), one row per pair i < j, and with the track (N, 2).
    stacked_refs = None
    if any(has_ref):
        stacked_refs = np.full((len(counts), JOINT_COUNT, 3), np.nan)
        stacked_refs[has_ref] = [ref for ref in references if ref is not None]
        stacked_refs = stacked_refs[person_of]
    pair, to_ref = lateral_terms(views, lay.first, lay.second, stacked_refs)

    # Where each person stands (mean SpineBase of its views) and the direction to each sensor.
    spine = views[:, 0]
    finite = np.isfinite(spine)
    # Sums per person over a zero-padded (P, S_max, 3) block: the same order as np.nanmean.
    padded = np.zeros((len(counts), lay.widest, 2, 3))
    padded[person_of, lay.slot_of, 0] = np.where(finite, spine, 0.0)
    padded[person_of, lay.slot_of, 1] = finite
    sums = padded.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        body = sums[:, 0] / sums[:, 1]
        to_sensor = (sensor_positions - body[person_of]) * _HORIZONTAL
        to_sensor /= np.sqrt((to_sensor * to_sensor).sum(-1, keepdims=True))

    known = None if prev is None else prev >= 0

    # The geometry term per view, (N, 2) for labels 0, 1: facing · direction to the sensor, in
    # the order matmul's own loop sums three products (the same bits as a (2, 3) @ (3, S)).
    per_label = np.zeros((total, 2))
    if geometric.any():
        assert reference_facings is not None
        facing = reference_facings[person_of]
        cos = (
            facing[:, 0] * to_sensor[:, 0]
            + facing[:, 1] * to_sensor[:, 1]
            + facing[:, 2] * to_sensor[:, 2]
        )
        cos = np.where(np.isnan(cos), 0.0, cos)  # np.nan_to_num (cos is finite or NaN)
        rows = geometric[person_of]
        per_label[rows, 0] = np.maximum(-cos[rows], 0.0)
        per_label[rows, 1] = np.maximum(cos[rows], 0.0)

    # The per-view tables, (N, 3, 2): track, geometry (known facing), anatomy.
    tables = np.zeros((total, 3, 2))
    tables[:, 0] = to_ref
    tables[:, 1] = per_label
    if anatomy is not None:
        tables[:, 2] = anatomy

    mirrored = np.zeros(total, dtype=bool)
    # Persons with the same number of views and the same kinds of terms are scored together:
    # (G, C) costs, every term summed in the order a single person's would be.
    for group in lay.groups:
        n, with_ref, known_facing = group.n, group.with_ref, group.known_facing
        combos = COMBOS[n]
        views_of = group.views_of.ravel()  # (G·n,)
        size = len(group.people)
        k = n * (n - 1) // 2
        block = pair[group.pair_rows].reshape(size, 4 * k)
        mine = mine_known = None
        if prev is not None and known is not None:
            mine, mine_known = prev[views_of].reshape(size, n), known[views_of].reshape(size, n)
        # (G, 3, 2n): each view's (label 0, label 1) per table, view-major.
        unary = tables[views_of].reshape(size, n, 3, 2).transpose(0, 2, 1, 3).reshape(size, 3, -1)
        geometry_sum = None
        if not known_facing:
            geometry_sum = np.stack(
                [
                    _candidate_geometry(
                        combos,
                        both[lo : lo + n],
                        None if forward is None else forward[lo : lo + n],
                        to_sensor[lo : lo + n],
                        rom_scale_deg,
                    ).sum(axis=1)
                    for lo in group.views_of[:, 0].tolist()
                ]
            )
        weights = [
            track_weight if with_ref else 0.0,
            geometry_weight_m if known_facing else 0.0,
            anatomy_weight_m if anatomy is not None else 0.0,
        ]

        # For many views, one matrix product first estimates every labelling's cost: a person
        # whose best estimate beats all others by more than rounding could ever explain has
        # its labelling (see screen); the others are scored exactly.
        exact = None
        if n >= SCREEN_FROM_VIEWS and geometry_sum is None:
            estimate = SWAP_PRIOR_M * np.tile(_LABELS, (size, n))
            for t, weight in enumerate(weights):
                if weight:
                    estimate = estimate + weight * unary[:, t]
            if mine is not None and mine_known is not None:
                changed = (_LABELS[None, None, :] != mine[:, :, None]) & mine_known[:, :, None]
                estimate = estimate + hysteresis_m * changed.reshape(size, 2 * n)
            clear = screen(n, block, estimate)
            settled = clear >= 0
            mirrored[group.views_of[settled]] = combos[clear[settled]].astype(bool)
            if settled.all():
                continue
            exact = np.flatnonzero(~settled)
            block, unary = block[exact], unary[exact]
            if mine is not None and mine_known is not None:
                mine, mine_known = mine[exact], mine_known[exact]

        # Exact costs of every labelling, (G, C), term by term as for one person alone.
        # Agreement between views: Σ over pairs i < j of D[i, j, c_i, c_j], pair by pair.
        cost = block[:, PAIR_TAKE[n]].sum(axis=1)
        # Each table: Σ over views of T[view, c_view], view by view (the last axis).
        sums = unary[:, :, VIEW_TAKE[n]].sum(axis=3)  # (G, 3, C)
        if with_ref:
            cost += track_weight * sums[:, 0]
        if geometry_sum is not None:
            cost += geometry_weight_m * geometry_sum
        else:
            cost += geometry_weight_m * sums[:, 1]
        if anatomy is not None:
            cost += anatomy_weight_m * sums[:, 2]
        cost += SWAP_PRIOR_M * SWAPS[n]
        if mine is not None and mine_known is not None:
            changed_all = (combos[None] != mine[:, None, :]) & mine_known[:, None, :]
            cost += hysteresis_m * changed_all.sum(axis=2)
        best = combos[np.argmin(cost, axis=1)]  # (G, n), the first minimum as np.argmin
        rows_of = group.views_of if exact is None else group.views_of[exact]
        mirrored[rows_of] = best.astype(bool)
    return mirrored, factors, forward


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
