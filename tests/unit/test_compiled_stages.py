"""The compiled stages as a whole: compiled once at start, then never again mid-stream; and the
helpers they share (:func:`skelfuse.jit.plain`, the weighted mean)."""

from __future__ import annotations

import importlib
import pkgutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import skelfuse.fusion
from skelfuse.fusion import weigh
from skelfuse.fusion.engine import warm_up
from skelfuse.jit import plain
from tests.support import random_views


def _compiled_loops() -> dict[str, Any]:
    """Every numba dispatcher defined in a fusion module, by ``module.name``."""
    from numba.core.registry import CPUDispatcher

    loops: dict[str, Any] = {}
    for info in pkgutil.iter_modules(skelfuse.fusion.__path__):
        module = importlib.import_module(f"skelfuse.fusion.{info.name}")
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__:
                loops[f"{info.name}.{name}"] = value
    return loops


def test_warm_up_compiles_every_loop_a_replay_runs(tmp_path: Path) -> None:
    """After :func:`warm_up`, whole replays (every stage, every input the pipeline passes, in the
    defaults and with the other golden settings) compile nothing more: no fused frame waits for
    a compilation. Loops the warm-up does not reach are named."""
    from tests.unit import test_golden_replay as golden

    warm_up()
    loops = _compiled_loops()
    assert len(loops) >= 20  # the discovery found the stages' loops
    before = {name: len(loop.signatures) for name, loop in loops.items()}
    cold = sorted(name for name, count in before.items() if count == 0)
    for config in sorted(golden.CONFIGS):
        golden.test_replay_output_matches_the_golden_output_within_its_rounding(config, tmp_path)
    after = {name: len(loop.signatures) for name, loop in loops.items()}
    grew = sorted(name for name in loops if after[name] > before[name])
    assert not grew, f"compiled during the replay, not by warm_up: {grew}"
    used_cold = sorted(name for name in cold if after[name] > 0)
    assert not used_cold, f"never compiled by warm_up: {used_cold}"


@pytest.mark.parametrize("seed", range(3))
def test_weighted_mean_matches_the_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    joints = random_views(seed)[:48].reshape(6, 8, 25, 3)
    weights = rng.uniform(-0.2, 1.0, joints.shape[:3])  # some negative: they count as 0
    weights[rng.random(weights.shape) < 0.2] = 0.0
    weights[1, :, :5] = 0.0  # joints no view carries: NaN
    weights[2, 0, 7] = np.nan
    for size in (8, 3, 1):
        points, w = joints[:, :size], weights[:, :size]
        usable = np.isfinite(points).all(axis=-1) & (w > 0)
        used = np.where(usable, w, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            expected = (used[..., None] * np.where(usable[..., None], points, 0.0)).sum(
                axis=1
            ) / used.sum(axis=1)[..., None]
        expected[used.sum(axis=1) <= 0] = np.nan
        fused = weigh.weighted_mean(points, w)
        np.testing.assert_allclose(fused, expected, rtol=0.0, atol=1e-6)
        assert np.isnan(fused).any() and np.isfinite(fused).any()
    one = weigh.weighted_mean(joints[:, :2], np.array([1.0, 0.5])[None, :, None])  # broadcast
    np.testing.assert_allclose(one, (joints[:, 0] + 0.5 * joints[:, 1]) / 1.5, atol=1e-6)


def test_plain_gives_kernels_writable_arrays_and_copies_a_table_once() -> None:
    writable = np.arange(6.0)
    assert plain(writable) is writable  # as it is
    table = np.arange(6)
    table.flags.writeable = False  # a shared index table: owns its data, never changes
    copy = plain(table, np.intp)
    assert copy is not table and copy.flags.writeable and np.array_equal(copy, table)
    assert plain(table, np.intp) is copy  # kept: copied once
    base = np.arange(4.0)
    view = np.broadcast_to(base, (2, 4))  # read-only, over data that may change
    assert np.array_equal(plain(view), [[0, 1, 2, 3]] * 2)
    base[0] = 9.0
    assert plain(view)[1, 0] == 9.0  # a view is copied afresh every time
    ints = plain([1, 2], np.float64)
    assert ints.dtype == np.float64 and ints.flags.writeable and ints.flags.c_contiguous
