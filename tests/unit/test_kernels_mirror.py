"""The mirror step's compiled kernels give the numpy path's bits and choices.

skelfuse.fusion.kernels_mirror (the agreement terms and the scoring of every labelling) and
skelfuse.fusion.kernels_facing (facings, unbiased facings) against the numpy code they replace,
on simulated views with noise, unknown joints and random points, persons of 1 … 10 views (from
6 views on the labellings are screened), and exact ties (copies of one view), where the first
minimum in numpy's summation order decides.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from skelfuse.fusion import anatomy, kernels, kernels_stages, label_scores, labels, mirror, walking
from skelfuse.fusion.mirror_distances import LATERAL_JOINTS, LATERAL_SWAP, lateral_terms
from skelfuse.fusion.mirror_labellings import layout
from tests.unit.test_kernels import _same_bits, _views

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


@pytest.mark.parametrize("seed", range(6))
def test_lateral_kernel_gives_the_numpy_bits(numba_kernels: None, seed: int) -> None:
    from skelfuse.fusion import kernels_mirror

    frame = _frame(seed)
    views = frame.views
    lay = layout(COUNTS, tuple((True, True) for _ in COUNTS))
    references = np.stack(frame.references)[lay.person_of]
    references[:4, 7] = np.nan  # joints the reference lacks
    pair, to_ref = np.empty((len(lay.first), 2, 2)), np.empty((len(views), 2))
    kernels_mirror.lateral_loop(
        views, LATERAL_JOINTS, LATERAL_SWAP, lay.first, lay.second, references,
        np.ones(len(views), dtype=bool), pair, to_ref,
    )  # fmt: skip
    expected_pair, expected_to_ref = lateral_terms(views, lay.first, lay.second, references)
    assert _same_bits(pair, expected_pair) and _same_bits(to_ref, expected_to_ref)
    assert np.isnan(views).any() and (pair == 0).any()  # unknown joints, rows with none known


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize(
    "weights",
    [{}, {"anatomy_weight_m": 0.0, "need_rom": False}, {"hysteresis_m": 0.0, "track_weight": 0.5}],
)
def test_scoring_kernel_chooses_as_numpy(
    numba_kernels: None, seed: int, weights: dict[str, float]
) -> None:
    frame = _frame(seed)
    mirrored, factors, forward = _choose(frame, **weights)
    with kernels.forced("numpy"):
        expected = _choose(frame, **weights)
    assert mirrored.tolist() == expected[0].tolist()
    for got, want in ((factors, expected[1]), (forward, expected[2])):
        assert got is want is None or (got is not None and want is not None)
        assert got is None or want is None or _same_bits(got, want)
    frame = replace(frame, previous=None)
    with kernels.forced("numpy"):
        expected = _choose(frame, **weights)
    assert _choose(frame, **weights)[0].tolist() == expected[0].tolist()


def test_scoring_kernel_takes_the_first_of_tied_labellings(numba_kernels: None) -> None:
    """A view and its mirror image, then three of each: swapping either side agrees as well, at
    the same prior. With the other terms 0 those labellings tie exactly and numpy's first
    minimum wins (the lower labelling index: the first views swapped), also after the screen."""
    view = _views(3)[2]
    image = view[mirror.PERMUTATION]
    views = np.stack([view, image, view, view, view, image, image, image])
    frame = replace(_frame(3, (2, 6)), views=views, previous=None)
    zero = {"geometry_weight_m": 0.0, "anatomy_weight_m": 0.0, "track_weight": 0.0}
    with kernels.forced("numpy"):
        expected = _choose(frame, **zero)[0]
    assert _choose(frame, **zero)[0].tolist() == expected.tolist()
    assert expected.tolist() == [True, False, True, True, True, False, False, False]


@pytest.mark.parametrize("seed", range(5))
def test_evidence_kernel_gives_the_numpy_bits(numba_kernels: None, seed: int) -> None:
    frame = _frame(seed)
    mirrored, factors, _ = _choose(frame)
    assert factors is not None
    factors = factors.copy()
    factors[1, 0, 3] = np.nan  # not finite: 0, as np.nan_to_num
    factors[2, 1, 4] = -np.inf  # a sum of +inf against the labelling: the largest float
    person_of = layout(COUNTS, tuple((True, True) for _ in COUNTS)).person_of
    per_view, evidence = kernels_stages.view_evidence(factors, mirrored, person_of, len(COUNTS))
    expected = label_scores.view_evidence(factors, mirrored)
    assert _same_bits(per_view, expected)
    assert _same_bits(evidence, np.bincount(person_of, expected, len(COUNTS)))
    assert per_view[1] == 0.0 and abs(per_view[2]) == np.finfo(np.float64).max


def test_walking_check_decides_as_numpy_at_the_boundary() -> None:
    """walking_backwards on Python floats takes the decisions np.linalg.norm and np.dot would,
    also where the velocity sits on the threshold (speed and dot product to the last bit)."""
    from skelfuse.fusion.settings import FusionSettings

    rng = np.random.default_rng(4)
    settings = FusionSettings(mirror_walk_check_s=0.5, mirror_walk_min_speed_mps=0.5)
    joints = _views(0)[0]
    decided = 0
    for _ in range(2000):
        angle = rng.uniform(0, 2 * np.pi)
        facing = np.array([np.sin(angle), 0.0, np.cos(angle)])
        side = np.array([np.cos(angle), 0.0, -np.sin(angle)])
        up = rng.uniform(-0.5, 0.5)  # cos = −0.5 to the facing: the threshold, up to rounding
        along = -0.5 + rng.normal(0, 1e-16)
        direction = along * facing + np.sqrt(0.75 - up**2) * side + [0.0, up, 0.0]
        velocity = rng.uniform(0.45, 0.55) * direction
        speed = float(np.linalg.norm(velocity))
        expected = speed >= 0.5 and float(np.dot(facing, velocity)) < -0.5 * speed
        got = walking.walking_backwards(joints, velocity, 1.0, 0.0, settings, facing)
        assert got == ((True, None) if expected else (False, None))
        decided += expected
    assert 0 < decided < 2000


def test_walking_backwards_now_decides_as_numpy_for_every_person() -> None:
    """On the threshold of speed and of direction (cos −0.5, to rounding), unknown facings."""
    rng = np.random.default_rng(5)
    count = 3000
    angle = rng.uniform(0, 2 * np.pi, count)
    facings = np.stack([np.sin(angle), np.zeros(count), np.cos(angle)], axis=1)
    side = np.stack([np.cos(angle), np.zeros(count), -np.sin(angle)], axis=1)
    up = rng.uniform(-0.5, 0.5, count)
    along = -0.5 + rng.normal(0, 1e-16, count)
    direction = along[:, None] * facings + np.sqrt(0.75 - up**2)[:, None] * side
    direction[:, 1] += up
    velocities = rng.uniform(0.45, 0.55, count)[:, None] * direction
    velocities[:5] = 0.5 * facings[:5] * [[-1.0, 1.0, -1.0]]  # backwards at exactly the speed
    facings[rng.random(count) < 0.05, rng.integers(0, 3)] = np.nan  # unknown facings
    got = walking.walking_backwards_now(velocities, facings, 0.5)
    expected = [
        bool(np.linalg.norm(v) >= 0.5 and np.isfinite(f).all())
        and float(np.dot(f, v)) < -0.5 * float(np.linalg.norm(v))
        for v, f in zip(velocities, facings, strict=True)
    ]
    assert got.tolist() == expected
    assert 0 < sum(expected) < count


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
