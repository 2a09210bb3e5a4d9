"""bench/moving/sensors.py on short runs: per-frame poses cut report B's erroneous frames, and
the fused error of mutual capture grows with the pose-to-frame mismatch (issue 15 item 5)."""

from __future__ import annotations

from bench.moving.frames import FrameCase, erroneous_frames
from bench.moving.fused import FusedCase, minimal_errors
from bench.moving.hub import hub_errors
from bench.moving.spaces import solved_spaces, stored_spaces


def test_per_frame_poses_cut_the_erroneous_frames_of_a_turning_head() -> None:
    # 3 s: still, 10° left, still; 2.5 m away a 10° turn moves the person ~40 cm.
    figures = erroneous_frames(FrameCase("yaw", seed=1, duration_s=3.0))
    fixed, per_frame = figures["fixed sensor"], figures["per-frame pose"]
    assert fixed["head"] > 30.0
    assert per_frame["head"] == 0.0
    for marker in ("left hand", "right hand", "left foot", "right foot"):
        assert per_frame[marker] < fixed[marker]


def test_an_ideal_sensor_with_per_frame_poses_makes_no_error() -> None:
    figures = erroneous_frames(FrameCase("roll", duration_s=2.0, noisy_sensor=False))
    assert max(figures["per-frame pose"].values()) == 0.0
    assert figures["fixed sensor"]["left foot"] > 0.0


def test_the_fused_error_grows_with_the_mismatch() -> None:
    # Five times report B's rate (up to 100°/s): 50 ms of mismatch is a 5° error in the pose.
    def case(mismatch_ms: float) -> FusedCase:
        return FusedCase("yaw", mismatch_ms, seed=1, turn_speed=5.0, duration_s=1.0)

    synced, late = minimal_errors(case(0.0)), minimal_errors(case(50.0))
    assert synced["coverage"] > 0.5
    assert late["mpjpe_mm"] > synced["mpjpe_mm"] + 10.0


def test_the_server_fuses_mutual_capture_and_feels_the_mismatch() -> None:
    def case(mismatch_ms: float) -> FusedCase:
        return FusedCase("yaw", mismatch_ms, seed=1, turn_speed=5.0, duration_s=1.0)

    synced, late = hub_errors(case(0.0)), hub_errors(case(50.0))
    assert synced["coverage"] > 0.5
    assert synced["mpjpe_mm"] < 100.0
    assert late["mpjpe_mm"] > synced["mpjpe_mm"] + 10.0


def test_each_wearer_in_their_own_space_stored_or_solved() -> None:
    case = FusedCase("yaw", 0.0, seed=1, duration_s=1.0)
    one = hub_errors(case)
    stored = hub_errors(case, stored_spaces(case.wearers))
    assert abs(stored["mpjpe_mm"] - one["mpjpe_mm"]) < 0.1  # only float rounding differs
    solved = solved_spaces(case)  # a skeleton calibration run over the calibration walk
    assert set(solved.calibration.spaces) == {"quest-0", "quest-1", "quest-2"}
    for rotation_deg, translation_mm in solved.errors.values():
        assert rotation_deg < 1.0 and translation_mm < 25.0, solved.errors
    assert hub_errors(case, solved)["mpjpe_mm"] < one["mpjpe_mm"] + 3.0
