"""The compiled interpolation of a step's pending rows gives the numpy path's bits.

skelfuse.fusion.kernels_lerp against world_views' numpy pass, through the function resolve
calls (``_interpolate_pending``), and against sensors._lerp sensor by sensor (the rule of one
sensor alone): joints missing in one frame or both, infinities, α below, at and above 0.5,
every tracking state, values over many magnitudes, and sensors that need no interpolation
between them.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import kernels, kernels_lerp, sensors, world_views
from skelfuse.fusion.sensors import BodyArrays
from skelfuse.protocol.skeleton import JOINT_COUNT


def _bodies(rng: np.random.Generator, count: int) -> BodyArrays:
    joints = rng.normal(0.0, 1.0, (count, JOINT_COUNT, 3)) * 10.0 ** rng.uniform(-3, 1.5)
    joints[rng.random(joints.shape) < 0.04] = np.nan
    joints[rng.random(joints.shape) < 0.01] = np.inf
    joints[rng.random(joints.shape) < 0.02] = -0.0
    states = rng.integers(0, 3, (count, JOINT_COUNT)).astype(np.uint8)
    return BodyArrays(list(range(count)), joints.astype(np.float32), states)


def _items(seed: int) -> list[BodyArrays | world_views._Pending]:
    rng = np.random.default_rng(seed)
    items: list[BodyArrays | world_views._Pending] = []
    for k in range(int(rng.integers(1, 17))):
        count = int(rng.integers(1, 7))
        if k % 5 == 3:
            items.append(_bodies(rng, count))  # a sensor needing no interpolation
            continue
        first, second = _bodies(rng, count), _bodies(rng, count)
        alpha = float((0.0, 0.5, 1.0, np.nextafter(0.5, 0.0))[k % 4] if k < 4 else rng.random())
        nearer = second if alpha >= 0.5 else first
        items.append(world_views._Pending(nearer, first, second, alpha))
    return items


@pytest.mark.parametrize("seed", range(30))
def test_compiled_interpolation_is_the_numpy_interpolation(numba_kernels: None, seed: int) -> None:
    items = _items(seed)
    with kernels.forced("numpy"), np.errstate(invalid="ignore"):  # inf − inf: unused
        want = world_views._interpolate_pending(items)
    calls = 0
    compiled = kernels_lerp.interpolated_rows

    def counted(*args: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nonlocal calls
        calls += 1
        return compiled(*args)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(kernels_lerp, "interpolated_rows", counted)
        got = world_views._interpolate_pending(items)
    pending = any(isinstance(item, world_views._Pending) for item in items)
    assert calls == int(pending)  # the kernel ran where there was anything to interpolate
    assert len(got) == len(want) == len(items)
    for mine, numpy_s, item in zip(got, want, items, strict=True):
        assert mine.tracking_ids == numpy_s.tracking_ids
        assert mine.joints_m.dtype == np.float32 and mine.states.dtype == np.uint8
        assert mine.joints_m.tobytes() == numpy_s.joints_m.tobytes()
        assert mine.states.tobytes() == numpy_s.states.tobytes()
        if isinstance(item, world_views._Pending):  # the rule of one sensor alone
            with np.errstate(invalid="ignore"):
                one = sensors._lerp(
                    item.first.joints_m,
                    item.first.states,
                    item.second.joints_m,
                    item.second.states,
                    item.alpha,
                )
            assert mine.joints_m.tobytes() == one[0].tobytes()
            assert mine.states.tobytes() == one[1].tobytes()
        else:
            assert mine is item


def test_float64_rows_take_numpy(numba_kernels: None) -> None:
    """A float64 body (not from a frame) is not rounded to float32 before the arithmetic."""
    rng = np.random.default_rng(3)
    first, second = _bodies(rng, 2), _bodies(rng, 2)
    wide = BodyArrays(first.tracking_ids, first.joints_m.astype(np.float64) + 1e-9, first.states)
    items: list[BodyArrays | world_views._Pending] = [world_views._Pending(wide, wide, second, 0.3)]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(kernels_lerp, "interpolated_rows", None)  # must not be called
        with np.errstate(invalid="ignore"):
            got = world_views._interpolate_pending(items)
    with kernels.forced("numpy"), np.errstate(invalid="ignore"):
        want = world_views._interpolate_pending(items)
    assert got[0].joints_m.tobytes() == want[0].joints_m.tobytes()
