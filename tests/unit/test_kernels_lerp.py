"""The compiled interpolation and move to the world of a step's rows gives the numpy path's bits.

skelfuse.fusion.kernels_lerp against world_views' numpy passes (``_interpolate_pending`` then
``bodies_to_world``), through the function resolve calls (``_compiled``), and against
sensors._lerp and protocol.transform.apply sensor by sensor (the rule of one sensor alone):
joints missing in one frame or both, infinities, α below, at and above 0.5, every tracking
state, values over many magnitudes, and sensors that need no interpolation between them.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import kernels, kernels_lerp, sensors, world_views
from skelfuse.fusion.sensors import BodyArrays
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.transform import Matrix4, apply, look_at_pose


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


def _poses(rng: np.random.Generator, count: int) -> list[Matrix4]:
    return [
        look_at_pose(tuple(rng.uniform(-4.0, 4.0, 3)), tuple(rng.uniform(-1.0, 1.0, 3)))
        for _ in range(count)
    ]


@pytest.mark.parametrize("seed", range(30))
def test_compiled_rows_are_the_numpy_rows(numba_kernels: None, seed: int) -> None:
    items = _items(seed)
    poses = _poses(np.random.default_rng(seed + 1000), len(items))
    with kernels.forced("numpy"), np.errstate(invalid="ignore"):  # inf − inf: unused
        want = world_views._interpolate_pending(items)
        want_worlds = world_views.bodies_to_world(poses, [a.joints_m for a in want])
    done = world_views._compiled(items, poses)
    assert done is not None
    (got, worlds), (world_rows, state_rows) = done
    assert len(got) == len(want) == len(worlds) == len(items)
    # The stacked rows are every item's, in order: what measured_from_arrays reads.
    assert world_rows.tobytes() == np.concatenate(worlds).tobytes()
    assert state_rows.tobytes() == np.concatenate([a.states for a in got]).tobytes()
    for mine, numpy_s, world, numpy_world, item, pose in zip(
        got, want, worlds, want_worlds, items, poses, strict=True
    ):
        assert mine.tracking_ids == numpy_s.tracking_ids
        assert mine.joints_m.dtype == np.float32 and mine.states.dtype == np.uint8
        assert mine.joints_m.tobytes() == numpy_s.joints_m.tobytes()
        assert mine.states.tobytes() == numpy_s.states.tobytes()
        assert world.dtype == np.float64 and world.shape == mine.joints_m.shape
        with np.errstate(invalid="ignore"):
            alone = apply(pose, mine.joints_m)  # the sensor alone
        # Every bit of a body without ±inf (the wire refuses ±inf: every body fusion sees);
        # where +inf and −inf meet (inf − inf) the NaN's sign depends on the operands' order
        # the compiler chose, so those compare as NaN.
        plain = ~np.isinf(mine.joints_m).any(axis=(1, 2))
        assert world[plain].tobytes() == numpy_world[plain].tobytes() == alone[plain].tobytes()
        assert np.array_equal(world, numpy_world, equal_nan=True)
        assert np.array_equal(world, alone, equal_nan=True)
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


def test_resolve_runs_the_loop_once_for_every_group(numba_kernels: None) -> None:
    rng = np.random.default_rng(5)
    items = _items(5)
    poses = _poses(rng, len(items))
    calls = 0
    compiled = kernels_lerp.to_world

    def counted(*args: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nonlocal calls
        calls += 1
        return compiled(*args)

    gathered = [(object(), pose, item) for pose, item in zip(poses, items, strict=True)]
    half = len(gathered) // 2
    with pytest.MonkeyPatch.context() as patch, np.errstate(invalid="ignore"):
        patch.setattr(kernels_lerp, "to_world", counted)
        groups = world_views.resolve([gathered[:half], gathered[half:]])  # type: ignore[list-item]
    assert calls == 1
    with kernels.forced("numpy"), np.errstate(invalid="ignore"):
        want = world_views.resolve([gathered[:half], gathered[half:]])  # type: ignore[list-item]
    for mine, numpy_s in zip(groups[0] + groups[1], want[0] + want[1], strict=True):
        assert np.array_equal(mine.world, numpy_s.world, equal_nan=True)  # ±inf: NaN's sign
        assert mine.bodies.joints_m.tobytes() == numpy_s.bodies.joints_m.tobytes()


def test_float64_rows_take_numpy(numba_kernels: None) -> None:
    """A float64 body (not from a frame) is not rounded to float32 before the arithmetic."""
    rng = np.random.default_rng(3)
    first, second = _bodies(rng, 2), _bodies(rng, 2)
    wide = BodyArrays(first.tracking_ids, first.joints_m.astype(np.float64) + 1e-9, first.states)
    items: list[BodyArrays | world_views._Pending] = [world_views._Pending(wide, wide, second, 0.3)]
    assert world_views._compiled(items, _poses(rng, 1)) is None
