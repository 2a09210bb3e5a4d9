"""The ``sim`` source's mutual-capture scenario: a moving sensor whose frames carry poses."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.agent.runner import make_hello
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sources.base import SensorError
from skelfuse.agent.sources.registry import make_source
from skelfuse.agent.sources.sim_mutual import MutualSimSource
from skelfuse.protocol.sensor_pose import pose_matrix
from skelfuse.protocol.transform import apply
from skelfuse.protocol.wire import Frame, decode, encode

T0_NS = 1_800_000_000 * 10**9
QUIET = KinectV2Params(
    jitter_base_m=0.0,
    jitter_per_m2=0.0,
    bias_trunk_m=0.0,
    bias_limb_m=0.0,
    bias_extremity_m=0.0,
    inferred_error_m=0.0,
    facing_bias=0.0,
    glitch_rate_hz=0.0,
    dropout_rate_hz=0.0,
)


def test_the_mutual_scenario_registers_as_moving_in_the_room() -> None:
    source = make_source("sim", {"scenario": "mutual", "wearer": 1, "persons": 2, "seed": 4})
    hello = make_hello("head-b", source)
    assert hello.moving and hello.pose_space == "room"
    assert hello.pose_hint is not None
    np.testing.assert_array_equal(hello.pose_hint, np.eye(4))  # the room is the world


def test_its_frames_carry_the_pose_that_places_the_others() -> None:
    source = MutualSimSource(0, 3, axis="pitch", params=QUIET, seed=2)
    for k in range(0, 90, 10):  # 3 s: the head pitches during the second one
        true_ns = T0_NS + k * 33_333_333
        capture = source.capture_at(true_ns)
        assert capture.pose is not None
        frame = decode(
            encode(Frame(k + 1, capture.t_capture_ns, capture.bodies, None, capture.pose))
        )
        assert isinstance(frame, Frame) and frame.pose == capture.pose
        truth = source.capture.truth(true_ns / 1e9)
        assert len(capture.bodies) >= 1
        for body in capture.bodies:
            placed = apply(pose_matrix(capture.pose), body.joints_m.astype(np.float64))
            nearest = min(
                float(np.nanmedian(np.linalg.norm(placed - truth[p], axis=1))) for p in (1, 2)
            )
            assert nearest < 1e-4


def test_bad_options_are_sensor_errors() -> None:
    with pytest.raises(SensorError, match="head axis"):
        make_source("sim", {"scenario": "mutual", "head_axis": "spin"})
    with pytest.raises(SensorError, match="wearer 3 of 3"):
        make_source("sim", {"scenario": "mutual", "wearer": 3})


def test_it_paces_frames_on_its_clock() -> None:
    now = [T0_NS]
    slept: list[float] = []

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        now[0] += round(seconds * 1e9)

    source = MutualSimSource(0, 2, wall_clock_ns=lambda: now[0], sleep=sleep)
    first = source.next_capture(1.0)
    second = source.next_capture(1.0)
    assert first is not None and second is not None
    assert second.t_capture_ns - first.t_capture_ns == round(1e9 / 30)
    assert slept == [pytest.approx(1 / 30)]
