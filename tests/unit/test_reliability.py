"""Per-joint view reliability (fusion/view_factors.py): lean, self-occlusion, relative factors."""

from __future__ import annotations

import math

import numpy as np

from bench.accuracy.oracle import best_view, group_mpjpe, view_errors
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.fusion.settings import BoneSettings, FusionSettings, SmoothingSettings, WeightSettings
from skelfuse.fusion.view_factors import hidden_by_trunk, lean_errors, reliability_factors
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import MIRROR_PERMUTATION, JointId as J

ERRORS = (0.021, 0.035, 0.06)


def _body(ankle_forward_m: float = 0.3) -> np.ndarray:
    """A standing body facing +Z at the origin, the left ankle ``ankle_forward_m`` ahead."""
    joints = np.zeros((25, 3))
    joints[:, 1] = 1.0
    joints[J.SPINE_BASE] = (0.0, 0.9, 0.0)
    joints[J.SPINE_MID] = (0.0, 1.2, 0.0)
    joints[J.SPINE_SHOULDER] = (0.0, 1.4, 0.0)
    joints[J.HIP_LEFT] = (0.1, 0.9, 0.0)
    joints[J.HIP_RIGHT] = (-0.1, 0.9, 0.0)
    joints[J.ANKLE_LEFT] = (0.1, 0.1, ankle_forward_m)
    joints[J.ANKLE_RIGHT] = (-0.1, 0.1, 0.0)
    return joints


def test_lean_is_zero_front_and_back_and_grows_with_radius_at_the_side() -> None:
    views = np.stack([_body()] * 3)
    lean = lean_errors(views, np.array([1.0, -1.0, 0.0]), 0.5)
    assert np.allclose(lean[:2], 0.0)
    # Side view: turned by 45°, the ankle at r = √(0.1² + 0.3²) moves 2·r·sin(22.5°).
    r = math.hypot(0.1, 0.3)
    assert math.isclose(lean[2, J.ANKLE_LEFT], 2 * r * math.sin(math.radians(22.5)), rel_tol=1e-9)
    assert lean[2, J.SPINE_BASE] == 0.0
    assert lean[2, J.ANKLE_LEFT] > lean[2, J.HIP_LEFT]


def test_unknown_facing_gives_no_lean() -> None:
    assert np.allclose(lean_errors(_body()[None], np.array([np.nan]), 0.5), 0.0)


def test_the_trunk_hides_the_far_wrist_from_a_side_sensor_only() -> None:
    body = _body(0.0)
    body[J.SPINE_SHOULDER] = (0.0, 1.4, 0.0)
    body[J.WRIST_LEFT] = (0.08, 1.0, 0.1)  # hands on the belly
    body[J.WRIST_RIGHT] = (-0.08, 1.0, 0.1)
    side = np.array([[-3.0, 1.0, 0.0]])  # on the person's right (they face +Z, left is +X)
    front = np.array([[0.0, 1.0, 3.0]])
    hidden_side = hidden_by_trunk(body[None], side)[0]
    assert hidden_side[J.WRIST_LEFT] and not hidden_side[J.WRIST_RIGHT]
    assert not hidden_side[J.ANKLE_LEFT]  # below the trunk
    assert not hidden_by_trunk(body[None], front)[0].any()
    assert not hidden_side[J.HIP_LEFT]  # trunk joints are on its surface


def test_the_front_view_wins_the_leaning_ankle_and_a_single_view_is_untouched() -> None:
    views = np.stack([_body(), _body()])
    cosines = np.array([1.0, 0.0])
    sensors = np.array([[0.0, 1.0, 3.0], [-3.0, 1.0, 0.0]])
    factors = reliability_factors(views, cosines, sensors, [0, 2], 0.5, ERRORS, 0.001, 0.08)
    assert factors[0, J.ANKLE_LEFT] == 1.0
    assert factors[1, J.ANKLE_LEFT] < 0.2
    assert factors[1, J.SPINE_BASE] > 0.9  # no lean at the pivot: only the depth jitter
    assert ((factors > 0) & (factors <= 1)).all()
    alone = reliability_factors(views[:1], cosines[1:], sensors[1:], [0, 1], 0.5, ERRORS, 0.001,
                                0.08)  # fmt: skip
    assert np.all(alone == 1.0)


def test_off_by_default_and_on_moves_the_fused_ankle_towards_the_front_view() -> None:
    assert FusionSettings().weights.view_reliability is False
    truth = _body()
    front = truth.copy()
    side = truth.copy()
    side[J.ANKLE_LEFT] += (0.0, 0.0, -0.12)  # the side view's ankle leans off
    states = np.full(25, 2, dtype=np.uint8)
    views = [
        View("front", 1, front, states, np.array([0.0, 1.0, 3.0])),
        View("side", 1, side, states, np.array([-3.0, 1.0, 0.0])),
    ]
    errors = {}
    for on in (False, True):
        settings = FusionSettings(
            weights=WeightSettings(view_reliability=on, facing=False),
            smoothing=SmoothingSettings(filter="none"),
            bones=BoneSettings(enforce=False),
        )
        pipeline = FusionPipeline(settings)
        out = []
        for n in range(5):
            out = pipeline.update(views, n / 30)
        errors[on] = float(np.linalg.norm(out[0].joints[J.ANKLE_LEFT] - truth[J.ANKLE_LEFT]))
    assert errors[True] < 0.5 * errors[False]


def test_the_oracle_picks_the_least_wrong_view_that_reports_enough_joints() -> None:
    good = np.full(25, 0.02)
    bad = np.full(25, 0.05)
    legless = np.full(25, 0.001)
    legless[[13, 14, 15, 17, 18, 19]] = np.nan  # legs out of the field of view
    chosen = best_view([bad, legless, good])
    assert chosen is good
    assert best_view([legless]) is None
    groups = group_mpjpe([good, bad])
    assert math.isclose(groups["all"], 35.0) and math.isclose(groups["legs"], 35.0)


def test_the_oracle_puts_a_mirrored_view_right_before_scoring_it() -> None:
    truth = _body()
    swapped = truth[list(MIRROR_PERMUTATION)]
    pose = np.eye(4)
    assert np.allclose(view_errors(swapped, True, pose, truth), 0.0)
    assert view_errors(swapped, False, pose, truth)[J.ANKLE_LEFT] > 0.1
