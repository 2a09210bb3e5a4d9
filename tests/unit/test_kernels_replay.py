"""The compiled re-phase replay gives the numpy path's floats, and so the same grid.

skelfuse.fusion.kernels_replay against alignment_replay.replayed_horizons' numpy passes
(split in parts from 129 candidates of 16 sensors on): candidates from 1 to 150, 1 to 16
sensors at 15, 30 and 60 fps, 2 to 128 frames (below, at and past the pairwise sum's blocks of
8), phases on a capture (a modulo of zero), delays from 0 to past the deadline, NaN; then a
policy driven with jitter re-phases to the same grid on both paths.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from skelfuse.fusion import alignment_replay, kernels, kernels_replay
from skelfuse.fusion.alignment import Alignment
from tests.unit.test_alignment import T0, P, _Drive


def _window(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    rng = np.random.default_rng(seed)
    sensors = int(rng.integers(1, 17))
    frames = int((2, 7, 8, 9, 17, 60, 128)[seed % 7] if seed < 14 else rng.integers(2, 129))
    candidates = int((1, 129, 150)[seed % 3] if seed < 6 else rng.integers(1, 151))
    periods = rng.choice([1 / 15, 1 / 30, 1 / 60], sensors)
    phase = rng.uniform(0.0, periods)[:, None]
    captures = (phase + rng.normal(0.0, 0.001 * (seed % 4), (sensors, frames))) % periods[:, None]
    delays = 0.002 + rng.exponential(0.001 * (seed % 5) + 1e-9, (sensors, frames))
    delays[rng.random(delays.shape) < 0.05] = 0.0
    grid = 1 / 30
    phases = rng.uniform(0.0, grid, candidates)
    phases[: min(candidates, sensors)] = captures[: min(candidates, sensors), 0]  # ahead = 0
    deadline = float(rng.choice([0.002, 0.007, 0.010, 0.020]))
    if seed % 2 == 0:  # seen exactly at the deadline there: on time
        delays[:, 0] = deadline
    return phases, captures, delays, periods, deadline


@pytest.mark.parametrize("seed", range(40))
def test_compiled_replay_is_the_numpy_replay(numba_kernels: None, seed: int) -> None:
    phases, captures, delays, periods, deadline = _window(seed)
    got = alignment_replay.replayed_horizons(phases, captures, delays, periods, deadline)
    with kernels.forced("numpy"):
        want = alignment_replay.replayed_horizons(phases, captures, delays, periods, deadline)
    for g, w in zip(got, want, strict=True):
        assert g.shape == w.shape and g.tobytes() == w.tobytes()


def test_the_windows_reach_late_and_on_time_sensors() -> None:
    """The windows above are not all late or all on time: the comparisons decide something."""
    mixed = 0
    for seed in range(40):
        window = _window(seed)
        with kernels.forced("numpy"):
            shares = alignment_replay.replayed_horizons(*window)[2]
        mixed += 0 < float(shares.mean()) < 1
    assert mixed >= 30


@pytest.mark.parametrize(
    ("which", "sensor", "frame"),
    [("delays", 1, 2), ("captures", -1, 5), ("captures", 0, 4), ("delays", 0, 1)],
)
def test_a_nan_reaches_the_same_answers(
    numba_kernels: None, which: str, sensor: int, frame: int
) -> None:
    """A NaN time is never late (a comparison with NaN is false) and its wait is NaN, whichever
    sensor has it: the first one's must not be replaced by the later ones', nor theirs lost."""
    phases, captures, delays, periods, deadline = _window(3)
    assert captures.shape[0] >= 3 and captures.shape[1] >= 6
    (delays if which == "delays" else captures)[sensor, frame] = np.nan
    got = kernels_replay.horizons(phases, captures, delays, periods, deadline)
    with kernels.forced("numpy"):
        want = alignment_replay.replayed_horizons(phases, captures, delays, periods, deadline)
    assert np.isnan(want[1]).any()
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("frames", [1, kernels_replay.MOST_FRAMES + 1])
def test_windows_the_loop_does_not_take_go_to_numpy(numba_kernels: None, frames: int) -> None:
    """One frame (numpy then sums over the sensors pairwise) and more than the loop's pairwise
    sum takes: numpy replays them, the same floats as ever."""
    phases, captures, delays, periods, deadline = _window(8)  # 8 frames, 16 sensors
    wide = np.tile(captures, (1, frames))[:, :frames]
    late = np.tile(delays, (1, frames))[:, :frames]
    with pytest.raises(ValueError, match="frames per sensor"):
        kernels_replay.horizons(phases, wide, late, periods, deadline)
    got = alignment_replay.replayed_horizons(phases, wide, late, periods, deadline)
    with kernels.forced("numpy"):
        want = alignment_replay.replayed_horizons(phases, wide, late, periods, deadline)
    assert all(g.tobytes() == w.tobytes() for g, w in zip(got, want, strict=True))


def test_the_policy_keeps_the_same_grid_on_both_paths(numba_kernels: None) -> None:
    """A deadline policy re-phasing every second through steady and jittery delivery: the same
    phases, instants and sensors not waited for with the replay compiled or not."""

    def run() -> list[tuple[float, frozenset[str]]]:
        policy = Alignment(
            "deadline", 30.0, deadline_s=0.007, grid="horizon", skip_expected_late=True,
            wait_for_phase=True,
        )  # fmt: skip
        drive = _Drive(policy)
        seen: list[tuple[float, frozenset[str]]] = []
        for k, jitter in enumerate((0.0, 0.001, 0.0005)):
            instants = drive.run(t + 3.0 * k, 3.0, jitter, seed=k)
            seen += [(i.t_s, policy.expected_late) for i in instants]
        return seen

    t = math.floor(T0 / P) * P
    mine = run()  # the compiled replay (the fixture's mode)
    with kernels.forced("numpy"):
        reference = run()
    assert mine == reference and len(mine) > 200
