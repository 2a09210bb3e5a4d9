"""Random sensor units stay within their documented spreads; the benchmark rig builds either
error model, and its default is the Kinect rig it always was."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import fields, replace

import numpy as np
import pytest

from bench.accuracy.oracle import view_errors
from bench.accuracy.runner import SimulatedRig
from bench.accuracy.scenarios import Scenario, scenarios
from skelfuse.agent.sim.kinect_model import KinectV2Params, SimulatedKinect
from skelfuse.agent.sim.performer import standing_pose
from skelfuse.agent.sim.sensor_units import (
    KINECT_SPREAD,
    TRACKER_SPREAD,
    ErrorModel,
    Spread,
    random_kinect_params,
    random_tracker_params,
)
from skelfuse.agent.sim.tracker_model import DepthTrackerParams, SimulatedDepthTracker, limb_swap
from skelfuse.agent.sources.sim import SimSource
from skelfuse.cli import build_parser
from skelfuse.cli.agent import source_from_args
from skelfuse.protocol.skeleton import JointId

J = JointId
Params = KinectV2Params | DepthTrackerParams


def _within(value: float, default: float, rule: Spread) -> bool:
    if rule.kind == "factor":
        return bool(rule.low * default - 1e-12 <= value <= rule.high * default + 1e-12)
    return rule.low <= value <= rule.high


@pytest.mark.parametrize(
    ("draw", "default", "spread"),
    [
        (random_kinect_params, KinectV2Params(), KINECT_SPREAD),
        (random_tracker_params, DepthTrackerParams(), TRACKER_SPREAD),
    ],
)
def test_random_units_stay_within_their_spread_and_differ(
    draw: Callable[[np.random.Generator], Params], default: Params, spread: dict[str, Spread]
) -> None:
    rng = np.random.default_rng(11)
    units = [draw(rng) for _ in range(300)]
    names = {f.name for f in fields(default)}
    assert set(spread) <= names, "every spread names a parameter"
    for name in names:
        values = [getattr(u, name) for u in units]
        if name not in spread:
            assert all(v == getattr(default, name) for v in values), f"{name} kept"
            continue
        rule, base = spread[name], getattr(default, name)
        assert all(_within(v, base, rule) for v in values), f"{name} out of its range"
        low, high = (rule.low * base, rule.high * base) if rule.kind == "factor" else (
            rule.low, rule.high)  # fmt: skip
        # 300 draws cover the range: both ends within 10 % of its (log) width.
        if rule.kind == "factor":
            width = math.log(rule.high / rule.low)
            assert math.log(min(values) / low) < 0.1 * width
            assert math.log(high / max(values)) < 0.1 * width
        else:
            assert min(values) - low < 0.1 * (high - low)
            assert high - max(values) < 0.1 * (high - low)
    assert len(set(units)) == len(units), "every unit its own"


def test_unknown_error_model_is_refused() -> None:
    with pytest.raises(ValueError, match="error model"):
        ErrorModel(kind="lidar")  # type: ignore[arg-type]


def _short(name: str, seconds: float = 1.0) -> Scenario:
    return replace(next(s for s in scenarios(True) if s.name == name), duration_s=seconds)


def test_the_default_rig_is_the_kinect_rig_it_always_was() -> None:
    scenario = _short("walking a circle")
    rig = SimulatedRig(scenario, 4, KinectV2Params())
    assert all(type(s) is SimulatedKinect for s in rig.sensors)
    # What the rig was built from before error models: a Kinect per pose, seed·100 + k.
    before = SimulatedRig(scenario, 4, KinectV2Params())
    before.sensors = [SimulatedKinect(p, KinectV2Params(), seed=400 + k)
                      for k, p in enumerate(before.poses)]  # fmt: skip
    captures, expected = list(rig.captures()), list(before.captures())
    assert len(captures) == len(expected) > 0
    for got, want in zip(captures, expected, strict=True):
        assert got.message == want.message and got.t_capture == want.t_capture
        assert all(o.true_joints is None for o in got.observations)


def test_the_rig_builds_trackers_and_random_units_seeded_by_the_run() -> None:
    scenario = _short("walking a circle")
    default = SimulatedRig(scenario, 4, KinectV2Params())
    trackers = SimulatedRig(scenario, 4, KinectV2Params(), ErrorModel("tracker"))
    assert all(type(s) is SimulatedDepthTracker for s in trackers.sensors)
    assert all(s.params == DepthTrackerParams() for s in trackers.sensors)
    seen = [o for c in trackers.captures() for o in c.observations]
    assert seen and all(o.true_joints is not None for o in seen)
    assert [c.t_capture for c in trackers.captures()] == [c.t_capture for c in default.captures()]
    for kind in ("kinect", "tracker"):
        model = ErrorModel(kind, random_sensors=True)  # type: ignore[arg-type]
        units = [s.params for s in SimulatedRig(scenario, 4, KinectV2Params(), model).sensors]
        again = [s.params for s in SimulatedRig(scenario, 4, KinectV2Params(), model).sensors]
        other = [s.params for s in SimulatedRig(scenario, 5, KinectV2Params(), model).sensors]
        assert units == again, "the run's seed decides the units"
        assert len(set(units)) == len(units), "every sensor its own unit"
        assert set(units).isdisjoint(other), "another seed, other units"


def test_the_oracle_puts_a_single_limb_swap_right_by_the_truth_permutation() -> None:
    truth = standing_pose()
    order = limb_swap((J.KNEE_LEFT, J.ANKLE_LEFT, J.FOOT_LEFT))
    reported = truth[order]
    pose = np.eye(4)
    assert np.allclose(view_errors(reported, False, pose, truth, order), 0.0)
    assert view_errors(reported, False, pose, truth)[J.ANKLE_LEFT] > 0.1


def test_the_live_sim_agent_can_run_the_tracker_model_or_a_random_unit() -> None:
    base = ["agent", "--id", "sim-a", "--source", "sim", "--seed", "7"]
    default = source_from_args(build_parser().parse_args(base))
    tracker = source_from_args(build_parser().parse_args([*base, "--error-model", "tracker"]))
    unit = source_from_args(build_parser().parse_args([*base, "--random-sensor"]))
    assert isinstance(default, SimSource) and isinstance(tracker, SimSource)
    assert isinstance(unit, SimSource)
    assert type(default.sensor) is SimulatedKinect and default.sensor.params == KinectV2Params()
    assert type(tracker.sensor) is SimulatedDepthTracker
    assert type(unit.sensor) is SimulatedKinect and unit.sensor.params != KinectV2Params()
    capture = tracker.capture_at(round(3.0e9))
    assert capture.bodies, "the tracker reports the room's people"
