"""The mirror scoring, its evidence, the walking check and the swap back, against plain-numpy
references written here: on simulated views with noise, unknown joints and random points,
persons of 1 … 10 views (from 6 views on, persons whose facing is known are screened), persons
never fused or with an unknown facing, and exact ties (copies of one view).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from skelfuse.fusion import anatomy, labels, mirror
from skelfuse.fusion.mirror_scores import LATERAL_JOINTS, LATERAL_SWAP, lateral_loop, layout
from skelfuse.fusion.settings import MirrorSettings
from tests.support import random_views as _views, same_bits as _same_bits

FloatArray = np.ndarray
COUNTS = (1, 2, 3, 4, 5, 6, 7, 8, 10)


@dataclass(frozen=True)
class Frame:
    """One frame's inputs to mirror.choose_labellings_and_forward."""

    views: FloatArray
    sensor_positions: FloatArray
    counts: tuple[int, ...]
    references: list[FloatArray]
    reference_facings: FloatArray
    previous: FloatArray | None


def _frame(seed: int, counts: tuple[int, ...] = COUNTS) -> Frame:
    """One frame's inputs to choose_labellings: persons of ``counts`` views each, some views
    copies of another (exact ties), sensors around, references with a known facing."""
    rng = np.random.default_rng(seed)
    pool = _views(seed)
    total = sum(counts)
    views = pool[rng.integers(0, len(pool), total)].copy()
    views[rng.integers(0, total, 6)] = views[0]  # copies: ties between labellings
    views[3] = views[3][mirror.PERMUTATION]  # a view and its mirror image
    views[-1] = np.nan  # a view that sees nothing
    views[-2, 4:] = np.nan  # and one that sees the spine only
    poses = pool[:36]  # the simulator's poses (with noise): a facing each
    references = [poses[rng.integers(0, len(poses))] + rng.normal(0, 0.05, (25, 3)) for _ in counts]
    facings = anatomy.facing_directions(np.stack(references))
    assert np.isfinite(facings).all()
    angles = rng.uniform(0, 2 * np.pi, total)
    sensors = np.stack([3 * np.sin(angles), np.full(total, 1.0), 3 * np.cos(angles)], axis=1)
    sensors[5] = views[5, 0]  # a sensor where the body stands: direction 0 / 0
    return Frame(views, sensors, counts, references, facings, rng.integers(-1, 2, total))


def _choose(
    frame: Frame, **weights: float
) -> tuple[np.ndarray, FloatArray | None, FloatArray | None]:
    settings = {
        "geometry_weight_m": 0.15,
        "hysteresis_m": 0.05,
        "track_weight": 1.0,
        "anatomy_weight_m": 0.1,
        "rom_scale_deg": 15.0,
    }
    settings.update(weights)
    return mirror.choose_labellings_and_forward(
        frame.views,
        frame.sensor_positions,
        frame.counts,
        frame.references,
        frame.reference_facings,
        frame.previous,
        need_rom=bool(settings.pop("need_rom", True)),
        **settings,
    )


def _mean_lateral(a: FloatArray, b: FloatArray) -> float:
    """The mean distance over the lateral joints finite in both views (25, 3), 0 if none."""
    d = np.linalg.norm(a[LATERAL_JOINTS] - b[LATERAL_JOINTS], axis=-1)
    return float(d[np.isfinite(d)].mean()) if np.isfinite(d).any() else 0.0


@pytest.mark.parametrize("seed", range(3))
def test_the_lateral_terms_are_mean_distances_under_both_labellings(seed: int) -> None:
    frame = _frame(seed)
    views = frame.views
    lay = layout(COUNTS)
    references = np.stack(frame.references)[lay.person_of]
    references[:4, 7] = np.nan  # joints the reference lacks
    has = np.ones(len(views), dtype=bool)
    has[5] = False  # a view without a reference: 0
    pair, to_ref = np.empty((len(lay.first), 2, 2)), np.empty((len(views), 2))
    lateral_loop(views, LATERAL_JOINTS, LATERAL_SWAP, lay.first, lay.second, references, has,
                 pair, to_ref)  # fmt: skip
    both = np.stack([views, views[:, mirror.PERMUTATION]], axis=1)
    for k, (i, j) in enumerate(zip(lay.first, lay.second, strict=True)):
        for a, b in np.ndindex(2, 2):
            assert abs(pair[k, a, b] - _mean_lateral(both[i, a], both[j, b])) < 1e-12
    for v in range(len(views)):
        for a in range(2):
            want = _mean_lateral(both[v, a], references[v]) if has[v] else 0.0
            assert abs(to_ref[v, a] - want) < 1e-12
    assert np.isnan(views).any() and (pair == 0).any()  # unknown joints, rows with none known


def _costs(frame: Frame, p: int, weights: dict[str, float]) -> np.ndarray:
    """Every labelling's cost for person p (the mirror module docstring, term by term)."""
    lo = sum(frame.counts[:p])
    n = frame.counts[p]
    views, sensors = frame.views[lo : lo + n], frame.sensor_positions[lo : lo + n]
    both = np.stack([views, views[:, mirror.PERMUTATION]], axis=1)  # (n, 2, 25, 3)
    factors, forward = anatomy.rom_factors_and_forward(both.reshape(-1, 25, 3), 15.0)
    factors, forward = factors.reshape(n, 2, 25), forward.reshape(n, 2, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        body = np.nanmean(views[:, 0], axis=0)
        to_sensor = anatomy.unit((sensors - body) * anatomy.HORIZONTAL)
    reference, facing = frame.references[p], frame.reference_facings[p]
    known = reference is not None and np.isfinite(facing).all()
    pairs = [[[_mean_lateral(both[i, a], both[j, b]) for b in range(2)] for a in range(2)]
             for i in range(n) for j in range(i + 1, n)]  # fmt: skip
    costs = np.empty(2**n)
    for combo in range(2**n):
        c = [(combo >> i) & 1 for i in range(n)]
        cost = sum(pairs[k][c[i]][c[j]] for k, (i, j) in enumerate(
            (i, j) for i in range(n) for j in range(i + 1, n)))  # fmt: skip
        if reference is not None:
            cost += weights["track_weight"] * sum(
                _mean_lateral(both[i, c[i]], reference) for i in range(n)
            )
        if not known:  # the facing the labelling itself implies
            summed = np.nan_to_num(forward[np.arange(n), c] * anatomy.HORIZONTAL).sum(0)
            with np.errstate(invalid="ignore", divide="ignore"):
                facing = summed / np.linalg.norm(summed)
        cos = np.nan_to_num(to_sensor @ facing)
        cost += weights["geometry_weight_m"] * sum(
            max(cos[i], 0.0) if c[i] else max(-cos[i], 0.0) for i in range(n)
        )
        cost += weights["anatomy_weight_m"] * sum((1 - factors[i, c[i]]).sum() for i in range(n))
        cost += mirror.SWAP_PRIOR_M * sum(c)
        if frame.previous is not None:
            before = frame.previous[lo : lo + n]
            cost += weights["hysteresis_m"] * sum(
                b >= 0 and b != ci for b, ci in zip(before, c, strict=True)
            )
        costs[combo] = cost
    return costs


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("edit", ["every facing known", "persons never fused", "facings unknown"])
def test_each_person_gets_its_cheapest_labelling(seed: int, edit: str) -> None:
    frame = _frame(seed, (1, 2, 3, 4, 6, 7, 3))
    if edit == "persons never fused":
        frame = replace(frame, references=[None, frame.references[1], None, *frame.references[3:]])
    elif edit == "facings unknown":
        facings = frame.reference_facings.copy()
        facings[[0, 2, 5]] = np.nan  # one of 7 views: not screened
        frame = replace(frame, reference_facings=facings)
    weights = {"geometry_weight_m": 0.15, "hysteresis_m": 0.05, "track_weight": 1.0,
               "anatomy_weight_m": 0.1}  # fmt: skip
    mirrored = _choose(frame, **weights)[0]
    compared = 0
    for p, lo in enumerate(np.cumsum((0, *frame.counts[:-1]))):
        costs = _costs(frame, p, weights)
        order = np.argsort(costs)
        if not costs[order[1]] - costs[order[0]] > 1e-9:  # a tie: rounding decides
            continue
        n = frame.counts[p]
        assert mirrored[lo : lo + n].tolist() == [bool((order[0] >> i) & 1) for i in range(n)]
        compared += 1
    assert compared >= 5


def test_the_first_of_tied_labellings_wins() -> None:
    """A view and its mirror image, then three of each: swapping either side agrees as well, at
    the same prior. With the other terms 0 those labellings tie exactly and the first
    labelling in index order wins (the first views swapped), also after the screen."""
    view = _views(3)[2]
    image = view[mirror.PERMUTATION]
    views = np.stack([view, image, view, view, view, image, image, image])
    frame = replace(_frame(3, (2, 6)), views=views, previous=None)
    zero = {"geometry_weight_m": 0.0, "anatomy_weight_m": 0.0, "track_weight": 0.0}
    chosen = _choose(frame, **zero)[0]
    assert chosen.tolist() == [True, False, True, True, True, False, False, False]


def test_the_evidence_is_the_joints_out_of_range_as_labelled_against_as_swapped() -> None:
    frame = _frame(1)
    mirrored, factors, _ = _choose(frame)
    assert factors is not None
    factors = factors.copy()
    factors[1, 0, 3] = np.nan  # not finite: 0
    factors[2, 1, 4] = -np.inf  # a sum of +inf against the labelling: the largest float
    per_view = labels.view_evidence(factors, mirrored)
    out_of_range = (1.0 - factors).sum(axis=2)
    rows = np.arange(len(mirrored))
    chosen = mirrored.astype(int)
    with np.errstate(invalid="ignore"):
        expected = np.nan_to_num(out_of_range[rows, chosen] - out_of_range[rows, 1 - chosen])
    np.testing.assert_allclose(per_view, expected, rtol=1e-12, atol=1e-12)
    assert per_view[1] == 0.0 and abs(per_view[2]) == np.finfo(np.float64).max
    summed = labels.evidence_against(factors, mirrored, frame.counts)
    person_of = layout(frame.counts).person_of
    np.testing.assert_allclose(summed, np.bincount(person_of, expected), rtol=1e-12)


MARGIN = 1e-9
"""Decisions closer than this to a threshold (speed or cos −0.5) are left out of the
comparisons: on them the last bit decides, and that bit depends on the CPU's loops."""


def _walks(rng: np.random.Generator, count: int) -> tuple[FloatArray, FloatArray]:
    """(count, 3) facings and velocities spread around both thresholds (speed 0.5 m/s, the
    velocity at 120° from the facing), some well inside, some well outside."""
    angle = rng.uniform(0, 2 * np.pi, count)
    facings = np.stack([np.sin(angle), np.zeros(count), np.cos(angle)], axis=1)
    side = np.stack([np.cos(angle), np.zeros(count), -np.sin(angle)], axis=1)
    along = rng.uniform(-0.7, -0.3, count)
    up = rng.uniform(-0.2, 0.2, count)
    direction = along[:, None] * facings + np.sqrt(1.0 - along**2 - up**2)[:, None] * side
    direction[:, 1] += up
    return facings, rng.uniform(0.4, 0.6, count)[:, None] * direction


def _expected(facing: FloatArray, velocity: FloatArray) -> bool | None:
    """Backwards (True), not (False), or None within :data:`MARGIN` of a threshold."""
    if not np.isfinite(facing).all():
        return False
    speed = float(np.linalg.norm(velocity))
    dot = float(np.dot(facing, velocity))
    if abs(speed - 0.5) < MARGIN or abs(dot + 0.5 * speed) < MARGIN:
        return None
    return speed >= 0.5 and dot < -0.5 * speed


def test_walking_check_decides_by_speed_and_direction() -> None:
    from skelfuse.fusion.settings import FusionSettings

    settings = FusionSettings(mirror=MirrorSettings(walk_check_s=0.5, walk_min_speed_mps=0.5))
    joints = _views(0)[0]
    facings, velocities = _walks(np.random.default_rng(4), 2000)
    decided = 0
    for facing, velocity in zip(facings, velocities, strict=True):
        expected = _expected(facing, velocity)
        if expected is None:
            continue
        got = mirror.walking_backwards(joints, velocity, 1.0, 0.0, settings, facing)
        assert got == ((True, None) if expected else (False, None))
        decided += expected
    assert 100 < decided < 1900


def test_walking_backwards_now_decides_for_every_person() -> None:
    """Every person at once, unknown facings among them (never backwards)."""
    rng = np.random.default_rng(5)
    facings, velocities = _walks(rng, 3000)
    facings[rng.random(3000) < 0.05, rng.integers(0, 3)] = np.nan  # unknown facings
    got = mirror.walking_backwards_now(velocities, facings, 0.5).tolist()
    expected = [_expected(f, v) for f, v in zip(facings, velocities, strict=True)]
    pairs = [(g, e) for g, e in zip(got, expected, strict=True) if e is not None]
    assert [g for g, _ in pairs] == [e for _, e in pairs]
    assert 100 < sum(e for _, e in pairs) < len(pairs) - 100


def test_settle_swaps_the_mirrored_views_back_in_place_whatever_their_layout() -> None:
    rng = np.random.default_rng(2)
    joints = _views(2)
    states = rng.integers(0, 3, joints.shape[:2]).astype(np.uint8)
    mirrored = rng.random(len(joints)) < 0.4
    reported = states.copy()
    expected_joints, expected_states = joints.copy(), states.copy()
    expected_joints[mirrored] = joints[mirrored][:, mirror.PERMUTATION]
    expected_states[mirrored] = states[mirrored][:, mirror.PERMUTATION]
    factors = rng.uniform(0.0, 1.0, (len(joints), 2, 25))
    _, rom = labels.settle((joints, states, mirrored), None, factors)
    assert _same_bits(joints, expected_joints) and _same_bits(states, expected_states)
    assert rom is not None
    assert _same_bits(rom, factors[np.arange(len(joints)), mirrored.astype(np.intp)])
    wide = np.repeat(expected_joints, 2, axis=0)[::2]  # strided, F-ordered: copied, written back
    flags = np.asfortranarray(expected_states)
    assert labels.settle((wide, flags, mirrored), None, None) == (None, None)
    assert np.array_equal(wide, _views(2), equal_nan=True)  # swapped back to as reported
    assert np.array_equal(flags, reported) and flags.flags.f_contiguous
