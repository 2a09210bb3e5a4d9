"""The confidence stage's loops against short numpy references written here.

skelfuse.fusion.confidence (each joint's weight from its view alone, with and without sensor
priors; the facing cosines; the confidence apps receive) and
skelfuse.fusion.weigh.carriers, on simulated views with noise, unknown joints and random
points, with and without each term: weights and factors to 1e-9.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from skelfuse.fusion import anatomy, confidence, view_factors, weigh
from skelfuse.fusion.priors import AZURE_BODY_TRACKING, KINECT_V2, RGB_MONO, SensorPrior
from skelfuse.fusion.settings import FusionSettings, WeightSettings
from skelfuse.protocol.skeleton import BONES, PARENTS
from tests.support import random_views as _views

TOLERANCE = 1e-9
"""Weights, factors and confidences: the loops and the references round differently at most."""


def _inputs(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Views, their tracking states, reference bone lengths (some unknown), rom factors."""
    rng = np.random.default_rng(seed)
    views = _views(seed)
    states = rng.integers(0, 3, views.shape[:2]).astype(np.uint8)
    parent, child = np.array(BONES).T
    lengths = np.linalg.norm(views[:36, child] - views[:36, parent], axis=-1)
    references = np.nanmedian(lengths, axis=0) * rng.uniform(0.8, 1.2, (len(views), len(BONES)))
    references[rng.random(references.shape) < 0.1] = np.nan
    rom = anatomy.rom_factors_and_forward(views, 15.0)[0]
    return views, states, references, rom


def _body_reference(
    views: np.ndarray,
    states: np.ndarray,
    references: np.ndarray | None,
    rom: np.ndarray | None,
    settings: FusionSettings,
    priors: list[SensorPrior],
) -> np.ndarray:
    """(state counts) × Π over the joint and its ancestors of (bone length × rom)."""
    s = settings
    local = np.ones(views.shape[:2])
    if s.weights.bone_length and references is not None:
        parent, child = np.array(BONES).T
        diff = np.abs(np.linalg.norm(views[:, child] - views[:, parent], axis=-1) - references)
        bones = np.where(np.isfinite(diff), np.exp(-diff / s.weights.bone_length_scale_m), 1.0)
        fixed = np.array([p.fixed_bone_lengths for p in priors])
        local[:, child] = np.where(fixed[:, None], 1.0, bones)
    if s.weights.range_of_motion and rom is not None:
        k = np.array([p.rom_scale for p in priors])[:, None]
        local = local * rom ** (1.0 / k)
    chained = local.copy()
    for joint in range(25):  # each joint times every ancestor's own factor
        parent = PARENTS[joint]
        while parent >= 0:
            chained[:, joint] *= local[:, parent]
            parent = PARENTS[parent]
    counts = np.array([p.table(s) for p in priors]) > 0
    weights = counts[np.arange(len(views))[:, None], states]
    result: np.ndarray = weights * chained
    return result


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize(
    "change",
    [{}, {"bone_length": False}, {"range_of_motion": False}, {"bone_length_scale_m": 0.2}],
)
def test_body_weights_match_the_reference(seed: int, change: dict[str, Any]) -> None:
    views, states, references, rom = _inputs(seed)
    settings = FusionSettings(weights=WeightSettings(**change))
    odd = SensorPrior("odd", state_weights=(0.1, 0.4, 0.8), rom_scale=2.0)
    kinds = [KINECT_V2, AZURE_BODY_TRACKING, RGB_MONO, odd]
    mixed = [kinds[i % 4] for i in range(len(views))]
    for refs, factors in ((references, rom), (None, None), (references, None)):
        for priors in (None, mixed):
            got = confidence.body_weights(views, states, refs, factors, settings, priors)
            own_rom = factors
            if own_rom is None and settings.weights.range_of_motion:
                own_rom = anatomy.rom_factors_and_forward(views, settings.weights.rom_scale_deg)[0]
            expected = _body_reference(
                views, states, refs, own_rom, settings, priors or [KINECT_V2] * len(views)
            )
            np.testing.assert_allclose(got, expected, rtol=0.0, atol=TOLERANCE)
    assert ((got > 0.0) & (got < 0.1)).any()  # the terms reach the weights


@pytest.mark.parametrize("seed", range(3))
def test_confidence_and_carriers_match_the_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    joints = _views(seed)[:120].reshape(6, 20, 25, 3)[:, :5].copy()
    weights = rng.uniform(-0.3, 1.4, joints.shape[:3])  # some negative, some above 1
    weights[rng.random(weights.shape) < 0.2] = 0.0
    weights[1, :, :4] = 0.0  # joints no view carries
    weights[2, 1, 6] = np.nan
    joints[3, :, 8] = np.nan  # joints no view sees
    for size in (5, 2, 1):
        points, w = joints[:, :size], weights[:, :size]
        seen = np.isfinite(points).all(axis=-1)
        used = np.where(seen & (w > 0), w, 0.0)
        expected = 1.0 - np.prod(1.0 - np.clip(used, 0.0, 1.0), axis=1)
        expected[used.sum(axis=1) <= 0] = 0.0
        final = np.where(seen, w, 0.0)
        total = final.sum(axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(total > 0, final / total, 0.0)
        carried = (share >= weigh.MIN_SHARE) & (final > 0)
        got = confidence.joint_confidence(points, w)
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=TOLERANCE)
        both = weigh.confidence_and_carriers(points, w)
        np.testing.assert_allclose(both[0], expected, rtol=0.0, atol=TOLERANCE)
        np.testing.assert_array_equal(both[1], carried)
        np.testing.assert_array_equal(weigh.carriers(points, w), carried)
    assert (got == 0).any() and carried.any() and not carried.all()


@pytest.mark.parametrize("seed", range(3))
def test_facing_cosines_match_the_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    count = 200
    angles = rng.uniform(0, 2 * np.pi, count)
    facings = np.stack([np.sin(angles), np.zeros(count), np.cos(angles)], axis=1)
    facings[:5] = np.nan  # persons whose facing is unknown
    bodies = rng.normal(0.0, 1.0, (count, 3))
    sensors = rng.normal(0.0, 3.0, (count, 3))
    sensors[5] = np.nan
    sensors[6] = bodies[6] + [0.0, 1.0, 0.0]  # straight above: no horizontal direction
    flat = (sensors - bodies) * [1.0, 0.0, 1.0]
    with np.errstate(invalid="ignore", divide="ignore"):
        expected = (flat / np.linalg.norm(flat, axis=-1, keepdims=True) * facings).sum(-1)
    cosines = view_factors.facing_cosines(facings, bodies, sensors)
    np.testing.assert_allclose(cosines, expected, rtol=0.0, atol=TOLERANCE)
    one = view_factors.facing_cosines(facings[9], bodies[9], sensors[:20])  # one person
    toward = (sensors[:20] - bodies[9]) * [1.0, 0.0, 1.0]
    mine = (toward / np.linalg.norm(toward, axis=-1, keepdims=True) * facings[9]).sum(-1)
    np.testing.assert_allclose(one, mine, rtol=0.0, atol=TOLERANCE)
    lone = view_factors.facing_cosines(facings[9], bodies[9], sensors[9])  # one view: a scalar
    assert lone.shape == () and lone == pytest.approx(expected[9], abs=TOLERANCE)
    assert np.isnan(cosines).sum() >= 6 and (cosines < 0).any()
