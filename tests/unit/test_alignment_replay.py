"""The re-phase replay (alignment.replayed_horizons) against the rule written in numpy.

Candidates from 1 to 150, 1 to 16 sensors at 15, 30 and 60 fps, 1 to 300 frames (below, at
and past the pairwise sum's blocks of 8 and of 128), phases on a capture (a modulo of zero),
delays from 0 to past the deadline, NaN.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import alignment


def _window(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    rng = np.random.default_rng(seed)
    sensors = int(rng.integers(1, 17))
    frames = int(
        (2, 7, 8, 9, 17, 60, 128, 129, 300, 1)[seed % 10] if seed < 20 else rng.integers(2, 129)
    )
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


def plain_rule(
    phases: np.ndarray,
    captures: np.ndarray,
    delays: np.ndarray,
    periods: np.ndarray,
    deadline: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The replay with a fresh array per step: the squared horizons of the late sensors summed
    over sensors, the last on-time sensor's wait, each sensor's late share."""
    ahead = np.mod(captures[None] - phases[:, None, None], periods[None, :, None])
    seen = ahead + delays[None]
    late = seen > deadline
    horizon = np.where(late, periods[None, :, None] - ahead, 0.0)
    return (
        (horizon**2).sum(axis=1).mean(axis=1),
        np.where(late, 0.0, seen).max(axis=1).mean(axis=1),
        late.mean(axis=2),
    )


@pytest.mark.parametrize("seed", range(40))
def test_the_replay_is_the_rule(seed: int) -> None:
    phases, captures, delays, periods, deadline = _window(seed)
    got = alignment.replayed_horizons(phases, captures, delays, periods, deadline)
    want = plain_rule(phases, captures, delays, periods, deadline)
    for g, w in zip(got, want, strict=True):
        assert g.shape == w.shape
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-15)


def test_the_windows_reach_late_and_on_time_sensors() -> None:
    """The windows above are not all late or all on time: the comparisons decide something."""
    mixed = 0
    for seed in range(40):
        shares = plain_rule(*_window(seed))[2]
        mixed += 0 < float(shares.mean()) < 1
    assert mixed >= 30


@pytest.mark.parametrize(
    ("which", "sensor", "frame"),
    [("delays", 1, 2), ("captures", -1, 5), ("captures", 0, 4), ("delays", 0, 1)],
)
def test_a_nan_reaches_the_same_answers(which: str, sensor: int, frame: int) -> None:
    """A NaN time is never late (a comparison with NaN is false) and its wait is NaN, whichever
    sensor has it: the first one's must not be replaced by the later ones', nor theirs lost."""
    phases, captures, delays, periods, deadline = _window(3)
    assert captures.shape[0] >= 3 and captures.shape[1] >= 6
    (delays if which == "delays" else captures)[sensor, frame] = np.nan
    got = alignment.replayed_horizons(phases, captures, delays, periods, deadline)
    want = plain_rule(phases, captures, delays, periods, deadline)
    assert np.isnan(want[1]).any()
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-15)  # NaN where NaN
