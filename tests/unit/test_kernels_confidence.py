"""The confidence stage's compiled kernels give the numpy path's bits.

skelfuse.fusion.kernels_confidence (each joint's weight from its view alone, the confidence apps
receive and the views that carried each joint) against the numpy code it replaces, on simulated
views with noise, unknown joints and random points, with and without each term.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.fusion import anatomy, confidence, kernels, weighted
from skelfuse.fusion.settings import FusionSettings
from skelfuse.protocol.skeleton import BONES
from tests.unit.test_kernels import _numpy_uses_svml, _same_bits, _views


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


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize(
    "change",
    [{}, {"use_bone_length": False}, {"use_range_of_motion": False}, {"bone_length_scale_m": 0.2}],
)
def test_body_weights_kernel_gives_the_numpy_bits(
    numba_kernels: None, seed: int, change: dict[str, object]
) -> None:
    views, states, references, rom = _inputs(seed)
    settings = FusionSettings(**change)  # type: ignore[arg-type]
    for refs, factors in ((references, rom), (None, None), (references, None)):
        got = confidence.body_weights(views, states, refs, factors, settings)
        with kernels.forced("numpy"):
            expected = confidence.body_weights(views, states, refs, factors, settings)
        if _numpy_uses_svml():  # numpy's own exp on AVX-512: a few ulp from the C library's
            np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0.0)
        else:
            assert _same_bits(got, expected)
    assert ((got > 0.0) & (got < 0.1)).any()  # the terms reach the weights


@pytest.mark.parametrize("seed", range(5))
def test_confidence_and_carriers_kernel_gives_the_numpy_bits(
    numba_kernels: None, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    joints = _views(seed)[:120].reshape(6, 20, 25, 3)[:, :5].copy()
    weights = rng.uniform(-0.3, 1.4, joints.shape[:3])  # some negative, some above 1
    weights[rng.random(weights.shape) < 0.2] = 0.0
    weights[1, :, :4] = 0.0  # joints no view carries
    weights[2, 1, 6] = np.nan
    joints[3, :, 8] = np.nan  # joints no view sees
    for size in (5, 2, 1):
        points, w = joints[:, :size], weights[:, :size]
        got = (confidence.joint_confidence(points, w), weighted.carriers(points, w))
        with kernels.forced("numpy"):
            expected = (confidence.joint_confidence(points, w), weighted.carriers(points, w))
        assert _same_bits(got[0], expected[0]) and _same_bits(got[1], expected[1])
        both = weighted.confidence_and_carriers(points, w)  # one compiled pass for the two
        with kernels.forced("numpy"):
            apart = weighted.confidence_and_carriers(points, w)
        for pair in (both, apart):
            assert _same_bits(pair[0], expected[0]) and _same_bits(pair[1], expected[1])
    assert (got[0] == 0).any() and got[1].any() and not got[1].all()


@pytest.mark.parametrize("seed", range(5))
def test_facing_kernels_give_the_numpy_bits(numba_kernels: None, seed: int) -> None:
    rng = np.random.default_rng(seed)
    count = 200
    angles = rng.uniform(0, 2 * np.pi, count)
    facings = np.stack([np.sin(angles), np.zeros(count), np.cos(angles)], axis=1)
    facings[:5] = np.nan  # persons whose facing is unknown
    bodies = rng.normal(0.0, 1.0, (count, 3))
    sensors = rng.normal(0.0, 3.0, (count, 3))
    sensors[5] = np.nan
    sensors[6] = bodies[6] + [0.0, 1.0, 0.0]  # straight above: direction 0 / 0
    cosines = confidence.facing_cosines(facings, bodies, sensors)
    with kernels.forced("numpy"):
        expected = confidence.facing_cosines(facings, bodies, sensors)
    assert _same_bits(cosines, expected)
    one = confidence.facing_cosines(facings[9], bodies[9], sensors[:20])  # one person
    with kernels.forced("numpy"):
        assert _same_bits(one, confidence.facing_cosines(facings[9], bodies[9], sensors[:20]))
    values = np.concatenate([cosines, [-1.5, 1.5, -0.0, 0.0, np.inf], rng.uniform(-1, 1, 5000)])
    for power, floor, back in ((2.0, 0.1, 0.5), (0.5, 0.2, 1.0), (1.7, 0.0, 0.3), (1.0, 0.4, 0.9)):
        got = confidence.facing_factors(values, power, floor, back)
        with kernels.forced("numpy"):
            want = confidence.facing_factors(values, power, floor, back)
        if _numpy_uses_svml() and power not in (2.0, 0.5, 1.0):  # SVML's pow on AVX-512
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
        else:
            assert _same_bits(got, want)
    assert np.isnan(cosines).sum() >= 6 and (cosines < 0).any()


def test_warm_up_compiles_every_stage_kernel_once(numba_kernels: None, tmp_path: Path) -> None:
    """After kernels.warm_up, a whole replay (every stage, every input the pipeline passes)
    adds no compilation: each loop keeps the signatures the warm-up compiled."""
    from skelfuse.fusion import (
        kernels_confidence,
        kernels_facing,
        labels,
        mirror_scores,
        unbiased_facing,
        walking,
    )
    from tests.unit import test_golden_replay as golden

    kernels.warm_up()
    loops = [
        mirror_scores.scored_loop, mirror_scores.evidence_loop,
        anatomy.facing_loop, anatomy.rom_loop, unbiased_facing.unbiased_loop,
        kernels_facing.cosines_loop, kernels_facing.facing_factors_loop,
        kernels_confidence.body_loop, kernels_confidence.confidence_loop,
        labels._settled_loop, walking._backwards_loop,
    ]  # fmt: skip
    compiled = [len(loop.signatures) for loop in loops]  # (other tests may add their own)
    golden.test_replay_output_is_byte_identical_to_the_golden_digest("", tmp_path)
    assert [len(loop.signatures) for loop in loops] == compiled
