"""bench/moving/reprojection.py's figures at 20° pitch + roll about the neck pivot, against
issue 15's targets for re-projection (holes about the input's own, ghosts <= 0.05 % of the
image)."""

from __future__ import annotations

from bench.moving.reprojection import case_figures


def test_the_20_degree_case_meets_the_targets() -> None:
    f = case_figures(20.0, 20.0, seed=2)
    # Mesh + points: holes near the level camera's own dropout; points alone leave many more.
    assert f["ideal mesh+points holes %"] <= 3.0
    assert f["noisy mesh+points holes %"] <= 3.0
    # Lone dropouts are filled from their neighbours: fewer holes than the level camera's own.
    assert f["noisy mesh+points holes %"] < f["own holes %"]
    assert f["noisy points holes %"] > 2.0 * f["noisy mesh+points holes %"]
    assert f["ideal mesh+points error mm"] <= 1.0
    assert f["noisy mesh+points error mm"] <= 6.0
    # Hard edges (no flying-pixel removal): the 10 cm rule is what keeps the ghosts out.
    assert f["hard edges mesh+points ghosts %"] <= 0.05
    assert f["noisy mesh+points ghosts %"] <= 0.05
    assert f["hard edges no rule ghosts %"] > 0.02
