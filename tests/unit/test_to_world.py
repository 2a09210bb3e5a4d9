"""A step's rows interpolated and moved to the world in one loop: the rule of one sensor alone.

skelfuse.fusion.world_views.to_world, through the function resolve calls (``_resolved_rows``),
against sensors._lerp and protocol.transform.apply sensor by sensor: joints missing in one
frame or both, infinities, α below, at and above 0.5, every tracking state, values over many
magnitudes, sensors that need no interpolation between them, and float64 bodies.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import sensors, world_views
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
def test_the_rows_are_each_sensors_interpolation_moved_by_its_pose(seed: int) -> None:
    items = _items(seed)
    poses = _poses(np.random.default_rng(seed + 1000), len(items))
    (got, worlds), (world_rows, state_rows) = world_views._resolved_rows(items, poses)
    assert len(got) == len(worlds) == len(items)
    # The stacked rows are every item's, in order: what measured_from_arrays reads.
    assert world_rows.tobytes() == np.concatenate(worlds).tobytes()
    assert state_rows.tobytes() == np.concatenate([a.states for a in got]).tobytes()
    for mine, world, item, pose in zip(got, worlds, items, poses, strict=True):
        assert mine.joints_m.dtype == np.float32 and mine.states.dtype == np.uint8
        assert world.dtype == np.float64 and world.shape == mine.joints_m.shape
        with np.errstate(invalid="ignore"):
            alone = apply(pose, mine.joints_m)  # the sensor alone
        # Where +inf and −inf meet (inf − inf) the NaN's sign depends on the operands' order
        # the compiler chose: compared as NaN.
        np.testing.assert_allclose(world, alone, rtol=0.0, atol=1e-6)
        if isinstance(item, world_views._Pending):  # the rule of one sensor alone
            with np.errstate(invalid="ignore"):
                one = sensors._lerp(
                    item.first.joints_m,
                    item.first.states,
                    item.second.joints_m,
                    item.second.states,
                    item.alpha,
                )
            assert mine.tracking_ids == item.nearer.tracking_ids
            np.testing.assert_allclose(mine.joints_m, one[0], rtol=0.0, atol=1e-6)
            np.testing.assert_array_equal(mine.states, one[1])
        else:
            assert mine is item


def test_resolve_runs_the_loop_once_for_every_group() -> None:
    rng = np.random.default_rng(5)
    items = _items(5)
    poses = _poses(rng, len(items))
    calls = 0
    compiled = world_views.to_world

    def counted(*args: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nonlocal calls
        calls += 1
        return compiled(*args)

    gathered = [(object(), pose, item) for pose, item in zip(poses, items, strict=True)]
    half = len(gathered) // 2
    with pytest.MonkeyPatch.context() as patch, np.errstate(invalid="ignore"):
        patch.setattr(world_views, "to_world", counted)
        groups = world_views.resolve([gathered[:half], gathered[half:]])  # type: ignore[list-item]
    assert calls == 1
    with np.errstate(invalid="ignore"):
        alone = world_views.resolve([gathered[:half]]) + world_views.resolve([gathered[half:]])  # type: ignore[list-item]
    for mine, one in zip(groups[0] + groups[1], alone[0] + alone[1], strict=True):
        assert np.array_equal(mine.world, one.world, equal_nan=True)  # ±inf: NaN's sign
        assert mine.bodies.joints_m.tobytes() == one.bodies.joints_m.tobytes()


def test_float64_rows_are_not_rounded_before_the_arithmetic() -> None:
    """A float64 body (not from a frame) is interpolated and moved in float64; only its
    interpolated joints are rounded to float32, as one sensor alone rounds them."""
    rng = np.random.default_rng(3)
    first, second = _bodies(rng, 2), _bodies(rng, 2)
    wide = BodyArrays(first.tracking_ids, first.joints_m.astype(np.float64) + 1e-9, first.states)
    poses = _poses(rng, 2)
    items: list[BodyArrays | world_views._Pending] = [
        world_views._Pending(wide, wide, second, 0.3),
        wide,
    ]
    with np.errstate(invalid="ignore"):
        (got, worlds), _ = world_views._resolved_rows(items, poses)
        one = sensors._lerp(wide.joints_m, wide.states, second.joints_m, second.states, 0.3)
        np.testing.assert_array_equal(got[0].joints_m, one[0])
        np.testing.assert_allclose(worlds[0], apply(poses[0], one[0]), rtol=0.0, atol=1e-9)
        # As it is: moved from its float64 joints, not from float32 ones.
        np.testing.assert_allclose(worlds[1], apply(poses[1], wide.joints_m), rtol=0.0, atol=1e-12)
    assert got[1] is wide
