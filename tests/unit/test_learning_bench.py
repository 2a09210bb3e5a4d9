"""The learned-errors benchmark's machinery on its smallest path: one short take and one short
move take (the figures are the benchmark's job, not this test's)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.accuracy.learning import (
    print_move_tables,
    print_oracle_table,
    print_spearman_table,
    print_targets_table,
)
from bench.accuracy.learning_runs import (
    FUSION,
    ORACLE,
    MovableSensor,
    SensorMove,
    run_move,
    run_take,
    spearman,
)
from bench.accuracy.scenarios import Scenario
from skelfuse.agent.sim.kinect_model import SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.scenarios import Segment
from skelfuse.agent.sim.sensor_units import ErrorModel
from skelfuse.fusion.rig_errors import GROUPS
from skelfuse.protocol.transform import look_at_pose

WALK = Scenario("walk", Segment(ProceduralPerformer(1), 0.0, 3.0), 3.0, 3, "walk")


def test_a_take_and_a_move_take_give_every_figure(capsys: pytest.CaptureFixture[str]) -> None:
    model = "kinect, random units"
    take = run_take(WALK, 0, ErrorModel("kinect", True), model)
    names = ["sim-1", "sim-2", "sim-3"]
    assert set(take.mpjpe) == {*FUSION, ORACLE, *(f"single {n}" for n in names)}
    for figures in take.mpjpe.values():
        assert set(figures) == {"all", *GROUPS}
    assert set(take.learned_mm) == set(take.true_mm) == set(names)
    for sensor in names:
        assert set(take.learned_mm[sensor]) == set(take.true_mm[sensor]) == set(GROUPS)
    assert set(take.spearman) == {"pooled", *GROUPS}
    bump = SensorMove(sensor=1, yaw_deg=5.0, shift_mm=100.0, at_s=1.5)
    move = run_move(WALK, 0, ErrorModel("kinect", False), "kinect, fixed units", bump)
    assert move.moved == "sim-2"
    assert [w["start_s"] for w in move.windows] == [0.0]  # one 5-s window in a 3-s take
    for part in (move.before, move.steady, move.rise_s, move.level_s, move.registered_after):
        assert set(part) == set(GROUPS)
    print_oracle_table([take])
    print_targets_table([take])
    print_spearman_table([take])
    print_move_tables([move], bump)
    out = capsys.readouterr().out
    for heading in ("hindsight oracle", "plain mean", "Spearman", "moved sensor"):
        assert heading in out, heading
    assert out.count("| kinect, random units | walk |") == 3  # one row in each take table


def test_spearman_ranks() -> None:
    assert spearman([1.0, 2.0, 3.0, 4.0], [10.0, 30.0, 20.0, 40.0]) == pytest.approx(0.8)
    assert spearman([1.0, 2.0, 3.0], [3.0, 2.0, 1.0]) == pytest.approx(-1.0)
    assert spearman([1.0, 2.0, math.nan, 3.0], [1.0, 2.0, 5.0, 3.0]) == pytest.approx(1.0)
    assert math.isnan(spearman([1.0, 2.0], [1.0, 2.0]))  # too few pairs


def test_a_moved_sensor_sees_what_a_sensor_standing_there_sees() -> None:
    """Same noise seed: the moved sensor's report equals a fresh sensor's at the new pose."""
    pose = look_at_pose((0.8, 1.0, 3.0), (0.0, 0.9, 0.0))
    moved_pose = SensorMove(0, 5.0, 100.0, 0.0).pose_after(pose)
    people = ProceduralPerformer(1).joints_at(1.0)
    moved = MovableSensor(SimulatedKinect(pose, seed=4))
    moved.move_to(moved_pose)
    there = SimulatedKinect(moved_pose, seed=4)
    a, b = moved.observe(people, 1.0), there.observe(people, 1.0)
    assert len(a) == len(b) == 1
    np.testing.assert_allclose(a[0].joints_m, b[0].joints_m, atol=1e-5)  # float32, metres
    np.testing.assert_array_equal(a[0].states, b[0].states)
    np.testing.assert_array_equal(moved.T_world_from_sensor, moved_pose)
    shift = moved_pose[:3, 3] - pose[:3, 3]
    assert shift[1] == 0.0 and np.linalg.norm(shift) == pytest.approx(0.1, abs=1e-12)
