"""The stacked views of one instant (fusion/weigh.py, ViewBatch): padding, and fusion as one
person alone."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion.views import View
from skelfuse.fusion.weigh import ViewBatch, weighted_mean
from skelfuse.protocol.skeleton import JOINT_COUNT


def views(rng: np.random.Generator, count: int) -> list[View]:
    out = []
    for k in range(count):
        joints = rng.normal(0.0, 1.0, (JOINT_COUNT, 3))
        joints[rng.random(JOINT_COUNT) < 0.2] = np.nan
        states = rng.integers(0, 3, JOINT_COUNT).astype(np.uint8)
        out.append(View(f"s{k}", k, joints, states, rng.normal(0.0, 3.0, 3)))
    return out


def padded_by_hand(
    batch: ViewBatch, values: npt.NDArray[np.float64], fill: float
) -> npt.NDArray[np.float64]:
    out = np.full((len(batch.counts), batch.widest, *values.shape[1:]), fill)
    for i, (p, s) in enumerate(zip(batch.person_of, batch.slot_of, strict=True)):
        out[p, s] = values[i]
    return out


@pytest.mark.parametrize("counts", [[3, 3, 3], [2, 3, 1], [1], [4, 4]])
def test_padding_puts_each_view_in_its_persons_row(counts: list[int]) -> None:
    rng = np.random.default_rng(len(counts))
    batch = ViewBatch.of([views(rng, n) for n in counts])
    assert batch.joints.dtype == np.float64 and batch.states.dtype == np.uint8
    for values, fill in ((batch.joints, np.nan), (rng.random((sum(counts), JOINT_COUNT)), 0.0)):
        got = batch.pad(values, fill)
        want = padded_by_hand(batch, values, fill)
        assert got.dtype == np.float64 and got.shape == want.shape
        assert got.tobytes() == want.tobytes()


def test_the_batch_holds_the_views_as_they_are() -> None:
    rng = np.random.default_rng(7)
    clusters = [views(rng, 2), views(rng, 3)]
    batch = ViewBatch.of(clusters)
    flat = [v for c in clusters for v in c]
    assert batch.joints.tobytes() == np.stack([v.joints_world for v in flat]).tobytes()
    assert batch.states.tobytes() == np.stack([v.states for v in flat]).tobytes()
    assert batch.sensors.tobytes() == np.stack([v.sensor_position for v in flat]).tobytes()
    assert batch.person_of.tolist() == [0, 0, 1, 1, 1]
    assert batch.slot_of.tolist() == [0, 1, 0, 1, 2]


@pytest.mark.parametrize("counts", [[3, 3], [1, 4, 2]])
def test_fusing_the_batch_is_fusing_each_person_alone(counts: list[int]) -> None:
    rng = np.random.default_rng(11)
    clusters = [views(rng, n) for n in counts]
    batch = ViewBatch.of(clusters)
    weights = rng.random((sum(counts), JOINT_COUNT))
    fused = batch.fuse(weights)
    for p in range(len(clusters)):
        lo, hi = batch.starts[p], batch.starts[p + 1]
        alone = weighted_mean(batch.joints[None, lo:hi], weights[None, lo:hi])[0]
        assert fused[p].tobytes() == alone.tobytes()


@pytest.mark.parametrize("counts", [[3, 3, 3], [2, 3, 1]])
def test_body_positions_fused_spine_else_the_mean_of_the_views(counts: list[int]) -> None:
    """Where a person's fused SpineBase is known, that point (the usual step: every person's);
    else the mean of its views' known SpineBases, NaN when none is known."""
    rng = np.random.default_rng(5)
    batch = ViewBatch.of([views(rng, n) for n in counts])
    fused = rng.normal(0.0, 1.0, (len(counts), JOINT_COUNT, 3))
    assert batch.body_positions(fused).tobytes() == fused[:, 0].tobytes()
    fused[1, 0, 2] = np.nan  # person 1: from its views
    fused[2, 0] = np.nan  # person 2: from its views, none of which knows its SpineBase
    lo, hi = batch.starts[2], batch.starts[3]
    batch.joints[lo:hi, 0] = np.nan
    batch.joints[batch.starts[1], 0] = np.nan  # one of person 1's views does not know it
    got = batch.body_positions(fused)
    assert got[0].tobytes() == fused[0, 0].tobytes()
    spines = batch.joints[batch.starts[1] : batch.starts[2], 0]
    known = spines[np.isfinite(spines).all(axis=1)]
    np.testing.assert_allclose(got[1], known.mean(axis=0), rtol=1e-15)
    assert np.isnan(got[2]).all()
