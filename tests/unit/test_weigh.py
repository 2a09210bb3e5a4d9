"""Steps 5–6 in one compiled loop give what the stages give term by term.

skelfuse.fusion.weigh.weigh_and_fuse runs the steps as one loop in phases, with the ray
weighting between them. It is compared with the stages called one after the other (body
weights, fusion, facing, each view's bins and learned variances, the Student-t pass, written
here in numpy, confidence and carriers) on simulated views with noise, unknown joints, unknown
sensor positions and facings, persons with different numbers of views, random learned
variances, and every setting that changes the path through the steps.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from skelfuse.fusion import weigh
from skelfuse.fusion.anatomy import facing_directions
from skelfuse.fusion.confidence import body_weights
from skelfuse.fusion.limb_labels import LIMBS, swap_limbs
from skelfuse.fusion.priors import KINECT_V2, SECTORS, SensorPrior, prior_variances, priors_of
from skelfuse.fusion.rig_errors import BINS
from skelfuse.fusion.settings import FusionSettings, LearningSettings, WeightSettings
from skelfuse.fusion.view_factors import facing_cosines
from skelfuse.fusion.views import View
from skelfuse.fusion.weigh import Learned, ViewBatch, confidence_and_carriers, weight_scale
from skelfuse.protocol.skeleton import BONES, JointId
from tests.support import random_views as _views

COUNTS = (4, 2, 3, 1, 4)
"""Views per person: different widths, so the persons are padded, and a person seen once."""


def _batch(seed: int, sensor_type: str = "kinect_v2") -> ViewBatch:
    rng = np.random.default_rng(seed)
    joints = _views(seed)
    states = rng.integers(0, 3, joints.shape[:2]).astype(np.uint8)
    sensors = rng.uniform(-4.0, 4.0, (len(joints), 3))
    sensors[rng.random(len(joints)) < 0.1] = np.nan  # sensors whose position is unknown
    clusters: list[list[View]] = []
    row = 0
    for count in COUNTS:
        own = []
        for k in range(count):
            joints[row, JointId.SPINE_BASE] = rng.normal(0.0, 0.5, 3) + [0.0, 1.0, 2.0]
            states[row, JointId.SPINE_BASE] = 2  # Tracked: every person stands somewhere
            own.append(View(f"s{k}", row, joints[row], states[row], sensors[row], sensor_type))
            row += 1
        clusters.append(own)
    return ViewBatch.of(clusters)


def _inputs(seed: int, batch: ViewBatch) -> tuple[Any, ...]:
    rng = np.random.default_rng(seed + 100)
    persons = len(batch.counts)
    references = rng.uniform(0.05, 0.5, (persons, len(BONES)))
    references[rng.random(references.shape) < 0.2] = np.nan
    references[1] = np.nan  # a person without reference lengths yet
    angle = rng.uniform(0, 2 * np.pi, persons)
    facings = np.stack([np.sin(angle), np.zeros(persons), np.cos(angle)], axis=1)
    facings[2] = np.nan  # a track whose facing is unknown
    rom = rng.uniform(0.2, 1.0, batch.joints.shape[:2])
    return rom, references, facings


def _learned(seed: int, batch: ViewBatch) -> Learned:
    """Each view's sensor a row of its own in a table of random variances around the prior."""
    rng = np.random.default_rng(seed + 200)
    table = prior_variances(KINECT_V2, FusionSettings())[None] * rng.uniform(
        0.3, 3.0, (len(batch.views), 1, BINS)
    )
    return Learned(np.arange(len(batch.views))[::-1].copy(), table)


def _bins(
    facing: np.ndarray, stands: np.ndarray, batch: ViewBatch, settings: FusionSettings
) -> tuple[np.ndarray, np.ndarray]:
    """Each view's joints' bins and how far towards the next sector (rig_errors.bin_of)."""
    flat = (batch.sensors - stands) * [1.0, 0.0, 1.0]
    distance = np.linalg.norm(flat, axis=1)
    along = (facing * flat).sum(axis=1)
    left = facing[:, 2] * flat[:, 0] - facing[:, 0] * flat[:, 2]
    with np.errstate(invalid="ignore"):
        position = (np.arctan2(left, along) % (2 * np.pi)) / (2 * np.pi / SECTORS)
    usable = np.isfinite(position) & (distance > 0) & settings.weights.view_bins
    sector = np.where(usable, np.minimum(np.floor(np.nan_to_num(position)), SECTORS - 1), 0)
    between = np.where(usable, np.nan_to_num(position) - sector, 0.0)
    far = settings.weights.view_bins & (distance > settings.learning.far_m)
    state = np.where(batch.states == 2, 0, 2)
    bins = (sector * 4)[:, None] + state + far[:, None]
    return np.where(batch.states == 0, -1, bins).astype(np.intp), between


def _robust(batch: ViewBatch, weights: np.ndarray, variances: np.ndarray, dof: float) -> np.ndarray:
    """The Student-t factor of each view's joint on its distance to the others' weighted mean."""
    out = np.ones(weights.shape)
    finite = np.isfinite(batch.joints).all(axis=-1)
    for lo, hi in zip(batch.starts[:-1], batch.starts[1:], strict=True):
        for k in range(lo, hi):
            others = [i for i in range(lo, hi) if i != k]
            w = np.where(finite[others] & (weights[others] > 0), weights[others], 0.0)
            total = w.sum(axis=0)
            x = np.nan_to_num(batch.joints[others])
            mean = (w[..., None] * x).sum(axis=0) / np.where(total > 0, total, 1.0)[:, None]
            spread = (w**2 * np.where(w > 0, variances[others], 0.0)).sum(axis=0)
            expected = variances[k] + spread / np.where(total > 0, total, 1.0) ** 2
            distance = ((batch.joints[k] - mean) ** 2).sum(axis=-1)
            with np.errstate(invalid="ignore"):
                factor = (dof + 3.0) / (dof + distance / expected)
            usable = (total > 0) & (weights[k] > 0) & finite[k]
            out[k] = np.where(usable, factor, 1.0)
    return out


def _weighed_by_views(
    batch: ViewBatch,
    rom: np.ndarray | None,
    references: np.ndarray,
    track_facings: np.ndarray,
    once: np.ndarray,
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None,
    learned: Learned,
) -> tuple[np.ndarray, ...]:
    """The body terms, the first fusion, the facing, the bins and the learned variances."""
    s = settings
    known = references[batch.person_of] if np.isfinite(references).any() else None
    weights = body_weights(batch.joints, batch.states, known, rom, s, priors)
    fused = batch.fuse(weights)
    facing = np.where(once[:, None], track_facings, facing_directions(fused))[batch.person_of]
    stands = batch.body_positions(fused)[batch.person_of]
    cosines = facing_cosines(facing, stands, batch.sensors)
    bins, between = _bins(facing, stands, batch, s)
    table = learned.variance[learned.rows[:, None], np.arange(25)]  # (N, 25, B)
    at = np.take_along_axis(table, np.maximum(bins, 0)[..., None], axis=2)[..., 0]
    after = np.take_along_axis(table, ((np.maximum(bins, 0) + 4) % BINS)[..., None], 2)[..., 0]
    a = between[:, None]
    geometric = np.where((a == 0) | (at == after), at, at ** (1 - a) * after**a)
    variances = np.where(bins >= 0, geometric, np.inf)
    weights = np.where(bins >= 0, weights * weight_scale(s) / variances, 0.0)
    return weights, batch.fuse(weights), cosines, bins, between, variances


def _term_by_term(
    batch: ViewBatch,
    rom: np.ndarray,
    references: np.ndarray,
    track_facings: np.ndarray,
    fused_once: Sequence[bool],
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None,
    learned: Learned,
    track_joints: np.ndarray,
) -> weigh.Weighed:
    """Steps 5–6 as the stages called one after the other (the reference)."""
    s = settings
    once = np.array(fused_once, dtype=bool)
    args = (references, track_facings, once, s, priors, learned)
    weights, fused, cosines, bins, between, variances = _weighed_by_views(batch, rom, *args)
    swapped = swap_limbs(batch.joints, batch.states, weights, batch.starts, (track_joints, once))
    if swapped.any():  # weighed again, the range-of-motion factors as they were
        weights, fused, cosines, bins, between, variances = _weighed_by_views(batch, rom, *args)
    if s.learning.robust_dof > 0:
        weights = weights * _robust(batch, weights, variances, s.learning.robust_dof)
        fused = batch.fuse(weights)
    padded_joints, padded_weights = batch.pad(batch.joints, np.nan), batch.pad(weights, 0.0)
    confidence, carried = confidence_and_carriers(padded_joints, padded_weights)
    return weigh.Weighed(weights, fused, cosines, confidence, carried, bins, between, variances)


def _both(
    batch: ViewBatch, fused_once: list[bool], settings: FusionSettings, seed: int
) -> tuple[weigh.Weighed, weigh.Weighed]:
    """The step from :func:`weigh.weigh_and_fuse` and from :func:`_term_by_term`, each on its
    own copy of ``batch``."""
    results = []
    for run in (weigh.weigh_and_fuse, _term_by_term):
        own = copy.deepcopy(batch)
        rom, references, facings = _inputs(seed, own)
        use = settings.weights.sensor_priors
        priors = priors_of([v.sensor_type for v in own.views]) if use else None
        learned = _learned(seed, own)
        tracks = own.joints[own.starts[:-1]].copy()  # each person's first view as its track
        results.append(
            run(own, rom, references, facings, fused_once, settings, priors, learned, tracks)
        )
    return results[0], results[1]


def _close(got: weigh.Weighed, expected: weigh.Weighed) -> None:
    """Weights, cosines and confidence to 1e-9 (relative for the weights and variances),
    positions to 1e-6 m, the carriers and bins equal."""
    for name, a, b in zip(got._fields, got, expected, strict=True):
        assert a.shape == b.shape, name
        if name in ("weights", "variances"):
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12, err_msg=name)
        elif a.dtype == np.bool_ or a.dtype == np.intp:
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            tolerance = 1e-6 if name == "fused" else 1e-9
            np.testing.assert_allclose(a, b, rtol=0.0, atol=tolerance, err_msg=name)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(
    "change",
    [{}, {"bone_length": False}, {"range_of_motion": False}, {"view_bins": False}],
)
def test_the_step_gives_the_stages_results(seed: int, change: dict[str, Any]) -> None:
    settings = FusionSettings(weights=WeightSettings(**change))
    got, expected = _both(_batch(seed), [True] * len(COUNTS), settings, seed)
    _close(got, expected)
    # The terms reached the result: weights below the state table's, views that did not carry.
    assert (got.weights[got.weights > 0] < 0.5).any() and not got.carried.all()
    assert np.isnan(got.cosines).any() and np.isfinite(got.fused).any()
    assert (got.bins == -1).any() and (got.bins >= 0).any()


@pytest.mark.parametrize("seed", range(3))
def test_a_person_whose_spine_no_view_sees_stands_at_its_views_mean(seed: int) -> None:
    batch = _batch(seed)
    batch.states[4:6, JointId.SPINE_BASE] = 0  # the second person's: positions of weight 0
    batch.joints[4, JointId.SPINE_BASE, 2] = np.nan  # (one coordinate of one unknown)
    got, expected = _both(batch, [True] * len(COUNTS), FusionSettings(), seed)
    _close(got, expected)
    assert np.isnan(got.fused[1, JointId.SPINE_BASE]).all()
    assert np.isfinite(got.cosines[5])  # it stands at its views' mean SpineBase


@pytest.mark.parametrize(
    ("case", "change", "fused_once", "sensor_type"),
    [
        ("a person fused the first time", {}, [True, False, True, True, False], "kinect_v2"),
        ("no bins by where sensors stand", {"view_bins": False}, [True] * 5, "kinect_v2"),
        ("no robust pass", {"robust_dof": 0.0}, [True] * 5, "kinect_v2"),
        ("a camera that guesses depth", {}, [True] * 5, "rgb"),
        ("depth guessed, no robust pass", {"robust_dof": 0.0}, [True] * 5, "rgb"),
        ("a sensor prior's own table", {}, [True] * 5, "azure_kinect"),
        ("priors off", {"sensor_priors": False}, [True] * 5, "azure_kinect"),
        ("every view near", {"far_m": 100.0}, [True] * 5, "kinect_v2"),
    ],
)  # fmt: skip
def test_every_setting_gives_the_stages_results(
    case: str, change: dict[str, Any], fused_once: list[bool], sensor_type: str
) -> None:
    learning = {k: v for k, v in change.items() if k in ("robust_dof", "far_m")}
    weights = {k: v for k, v in change.items() if k not in learning}
    settings = FusionSettings(
        weights=WeightSettings(**weights), learning=LearningSettings(**learning)
    )
    batch = _batch(3, sensor_type)
    if sensor_type == "azure_kinect":  # (its prior must differ from the settings to count)
        assert any(
            p != SensorPrior("kinect_v2") for p in priors_of([v.sensor_type for v in batch.views])
        )
    got, expected = _both(batch, fused_once, settings, 3)
    _close(got, expected)
    assert np.isfinite(got.fused).any(), case


def test_a_view_with_its_arms_swapped_is_put_right_within_the_step() -> None:
    rng = np.random.default_rng(5)
    body = _views(0)[0]
    body[:, :] = np.linspace([0.0, 0.1, 2.0], [0.0, 1.7, 2.0], 25)  # a column, arms apart:
    body[LIMBS[0]] += (0.4, 0.0, 0.0)
    body[LIMBS[1]] -= (0.4, 0.0, 0.0)
    views = [body + rng.normal(0.0, 0.01, body.shape) for _ in range(3)]
    truth = views[2].copy()
    left, right = LIMBS[0], LIMBS[1]
    views[2][left], views[2][right] = truth[right], truth[left]
    states = np.full(25, 2, np.uint8)
    sensors = [np.array([0.0, 1.0, 5.0]), np.array([4.0, 1.0, 0.0]), np.array([-4.0, 1.0, 0.0])]
    batch = ViewBatch.of(
        [[View(f"s{k}", k, views[k], states.copy(), sensors[k]) for k in range(3)]]
    )
    learned = Learned(
        np.zeros(3, dtype=np.intp), prior_variances(KINECT_V2, FusionSettings())[None]
    )
    weigh.weigh_and_fuse(
        batch, None, np.full((1, 24), np.nan), np.full((1, 3), np.nan), [False],
        FusionSettings(), None, learned, np.zeros((1, 25, 3)),
    )  # fmt: skip
    np.testing.assert_allclose(batch.joints[2], truth, atol=1e-12)
