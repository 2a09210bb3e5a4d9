"""The accuracy benchmark's own machinery, on a short scenario (the figures are its job)."""

from __future__ import annotations

import math

import pytest

from bench.accuracy.methods import BASELINE, FULL, METHODS
from bench.accuracy.metrics import Log
from bench.accuracy.report import group_row
from bench.accuracy.runner import run_once
from bench.accuracy.scenarios import Scenario
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.scenarios import Segment


def test_a_short_run_gives_every_metric_and_the_full_method_wins() -> None:
    scenario = Scenario("walk", Segment(ProceduralPerformer(1), 0.0, 3.0), 3.0, 3, "walk")
    methods = {name: METHODS[name] for name in (BASELINE, FULL)}
    result = run_once(scenario, seed=1, params=KinectV2Params(), methods=methods)
    assert set(result) == {BASELINE, FULL, "single sim-1", "single sim-2", "single sim-3"}
    for metrics in result.values():
        assert 0.0 < metrics["mpjpe_mm"] < 1000.0, metrics
        assert 0.0 <= metrics["erroneous"] <= 1.0 and 0.0 < metrics["coverage"] <= 1.0
        assert metrics["duplicates"] == 0.0
    full, base = result[FULL], result[BASELINE]
    # Mirror correction and the rest: far better than report A's weights even in 3 s.
    assert full["mpjpe_mm"] < 0.7 * base["mpjpe_mm"], (full, base)
    # Bone lengths are fitted every frame once the estimate exists: their spread is small.
    assert full["bone_cv"] < base["bone_cv"]
    assert math.isfinite(full["bone_cv_settled"]) and full["bone_cv_settled"] <= full["bone_cv"]


def test_metrics_follow_their_definitions() -> None:
    """Two frames of one person, exact then 20 cm off at the head: known MPJPE, p95, errors."""
    truth = ProceduralPerformer(1).joints_at(1.0)
    log = Log()
    log.add(1, [(7, truth[0].copy())], truth)
    moved = truth[0].copy()
    moved[3] += [0.2, 0.0, 0.0]  # HEAD
    log.add(2, [(7, moved)], truth)
    summary = log.summary()
    assert summary["mpjpe_mm"] == pytest.approx(200.0 / 50)  # one joint in 50 is 200 mm off
    assert summary["erroneous"] == 0.5  # the head is one of report B's joints
    assert summary["id_switches"] == 0.0 and summary["coverage"] == 1.0
    assert group_row([{**summary, "mpjpe_mm": v} for v in (1.0, 2.0, 9.0)])["mpjpe_mm"] == 2.0
