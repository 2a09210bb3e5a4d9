"""Priors per sensor type (fusion/priors.py): Kinect v2 unchanged, Azure its own, types mixed."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from skelfuse.agent.sim.performer import BodyShape, Pose, pose_joints
from skelfuse.fusion.confidence import body_weights
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.fusion.priors import (
    AZURE_BODY_TRACKING,
    KINECT_V2,
    PRIORS,
    RGB_MONO,
    SensorPrior,
    distinct_priors,
    prior_for,
    prior_variances,
    priors_of,
)
from skelfuse.fusion.rig_errors import BINS, bin_of
from skelfuse.fusion.settings import (
    BoneSettings,
    FusionSettings,
    SmoothingSettings,
    TrackingSettings,
)
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, bone_lengths
from skelfuse.protocol.wire import SENSOR_TYPES

SETTINGS = FusionSettings()


def body(x: float = 0.0) -> np.ndarray:
    return pose_joints(BodyShape(1.75), Pose(), (x, 0.0), 0.0)


def noisy_views(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 25, 3) views with 3 cm noise, random states, and a reference 2 cm off per bone."""
    rng = np.random.default_rng(seed)
    joints = body()[None] + rng.normal(0.0, 0.03, (n, JOINT_COUNT, 3))
    states = rng.integers(0, 3, (n, JOINT_COUNT)).astype(np.uint8)
    reference = bone_lengths(body()) + 0.02
    return joints, states, np.repeat(reference[None], n, axis=0)


def test_every_wire_type_has_a_prior_and_the_v2_like_ones_are_the_settings() -> None:
    assert set(SENSOR_TYPES) <= set(PRIORS)
    assert PRIORS["rgb"] is RGB_MONO and RGB_MONO.depth_noise_ratio > 1  # depth along the ray
    for name in ("kinect_v2", "sim", "replay"):
        prior = PRIORS[name]
        assert dataclasses.replace(prior, name="kinect_v2") == KINECT_V2
        assert prior.table(SETTINGS) == SETTINGS.weights.state_weights
    femto = dataclasses.replace(PRIORS["femto"], name=AZURE_BODY_TRACKING.name)
    assert femto == AZURE_BODY_TRACKING  # the same Body Tracking SDK


def test_kinect_v2_prior_gives_the_settings_body_factors_bit_for_bit() -> None:
    joints, states, refs = noisy_views(6)
    joints[2, JointId.ELBOW_LEFT] += (0.0, -0.2, 0.25)  # a glitch: out of range, bone off
    priors = [KINECT_V2] * 6
    today = body_weights(joints, states, refs, None, SETTINGS)
    assert np.array_equal(body_weights(joints, states, refs, None, SETTINGS, priors), today)
    assert (today[states > 0] < 1.0).any()  # the body terms bite
    assert (today[states == 0] == 0.0).all()  # a state of prior weight 0 never counts
    assert ((today >= 0.0) & (today <= 1.0)).all()


def test_prior_variances_follow_the_direction_state_and_distance() -> None:
    table = prior_variances(KINECT_V2, SETTINGS)  # (25, B)
    assert table.shape == (JOINT_COUNT, BINS)
    knee = JointId.KNEE_LEFT
    front = table[knee, bin_of(0, True, False)]
    assert front == pytest.approx(KINECT_V2.error_m[1] ** 2)
    side = table[knee, bin_of(2, True, False)]
    back = table[knee, bin_of(4, True, False)]
    assert side == pytest.approx(front * KINECT_V2.side_ratio)
    assert back == pytest.approx(front * KINECT_V2.back_ratio)
    assert front < table[knee, bin_of(1, True, False)] < side  # between, by sin²
    assert table[knee, bin_of(6, True, False)] == pytest.approx(side)  # left and right alike
    weights = SETTINGS.weights.state_weights
    assert table[knee, bin_of(0, False, False)] == pytest.approx(front * weights[2] / weights[1])
    assert table[knee, bin_of(0, True, True)] == pytest.approx(front * KINECT_V2.far_ratio)
    trunk = table[JointId.SPINE_MID, bin_of(0, True, False)]
    hand = table[JointId.HAND_LEFT, bin_of(0, True, False)]
    assert trunk < front < hand  # trunk, limb, extremity
    never = dataclasses.replace(KINECT_V2, state_weights=(0.0, 0.0, 0.7))
    assert np.isinf(prior_variances(never, SETTINGS)[knee, bin_of(0, False, False)])
    twice = dataclasses.replace(KINECT_V2, error_m=tuple(2 * e for e in KINECT_V2.error_m))
    np.testing.assert_allclose(prior_variances(twice, SETTINGS), 4 * table, rtol=1e-12)


def test_azure_view_gets_its_own_table_and_no_bone_length_term() -> None:
    joints, states, refs = noisy_views(1)
    joints[0, JointId.KNEE_LEFT] = joints[0, JointId.HIP_LEFT] + (0.0, -0.55, 0.0)  # long thigh
    v2 = body_weights(joints, states, refs, None, SETTINGS, [KINECT_V2])
    azure = body_weights(joints, states, refs, None, SETTINGS, [AZURE_BODY_TRACKING])
    no_bones = body_weights(
        joints,
        states,
        refs,
        None,
        dataclasses.replace(
            SETTINGS, weights=dataclasses.replace(SETTINGS.weights, bone_length=False)
        ),
    )
    assert np.array_equal(azure, no_bones)  # its fixed-length model's offset is not noise
    knee = JointId.KNEE_LEFT
    assert states[0, knee] == 0 or azure[0, knee] > v2[0, knee]

    own = dataclasses.replace(AZURE_BODY_TRACKING, state_weights=(0.0, 0.5, 0.9))
    weights = body_weights(joints, states, refs, None, SETTINGS, [own])
    settings_nb = dataclasses.replace(
        SETTINGS,
        weights=dataclasses.replace(
            SETTINGS.weights, bone_length=False, state_weights=(0, 0.5, 0.9)
        ),
    )
    assert np.array_equal(weights, body_weights(joints, states, refs, None, settings_nb))


def test_mixed_types_in_one_batch_each_row_as_alone() -> None:
    joints, states, refs = noisy_views(4, seed=3)
    loose_prior = dataclasses.replace(AZURE_BODY_TRACKING, rom_scale=2.0)
    priors = [KINECT_V2, loose_prior, RGB_MONO, KINECT_V2]
    mixed = body_weights(joints, states, refs, None, SETTINGS, priors)
    for i, prior in enumerate(priors):
        alone = body_weights(
            joints[i : i + 1], states[i : i + 1], refs[i : i + 1], None, SETTINGS, [prior]
        )
        np.testing.assert_allclose(mixed[i], alone[0], rtol=1e-15)
    assert np.array_equal(mixed[[0, 3]], body_weights(joints, states, refs, None, SETTINGS)[[0, 3]])


def test_range_of_motion_scale() -> None:
    joints, states, refs = noisy_views(1, seed=5)
    joints[0, JointId.ANKLE_LEFT] = joints[0, JointId.KNEE_LEFT] + (0.0, 0.0, -0.45)  # knee bent
    base = SensorPrior("x", fixed_bone_lengths=True)
    loose = body_weights(
        joints, states, refs, None, SETTINGS, [dataclasses.replace(base, rom_scale=2.0)]
    )
    wider = dataclasses.replace(
        SETTINGS,
        weights=dataclasses.replace(
            SETTINGS.weights, rom_scale_deg=2.0 * SETTINGS.weights.rom_scale_deg
        ),
    )
    np.testing.assert_allclose(loose, body_weights(joints, states, refs, None, wider, [base]))


def test_unknown_type_falls_back_to_kinect_v2_with_one_warning(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with caplog.at_level(logging.WARNING, logger="skelfuse.fusion.priors"):
        assert prior_for("gizmo_test_priors") is KINECT_V2
        assert priors_of(["gizmo_test_priors", "azure_kinect"]) == [KINECT_V2, AZURE_BODY_TRACKING]
    warnings = [r for r in caplog.records if "gizmo_test_priors" in r.getMessage()]
    assert len(warnings) == 1


def test_distinct_priors_by_value_and_kept_answers_stay_right() -> None:
    """Equal priors count as one (by value, as hashing them did), each view's index follows the
    sequence given, and a kept answer (frames repeat) is the same and cannot be written to."""
    twin = dataclasses.replace(KINECT_V2)  # equal to Kinect v2's, another object
    assert twin == KINECT_V2 and twin is not KINECT_V2
    for _ in range(2):  # the second time from what was kept
        found, of_view = distinct_priors([RGB_MONO, KINECT_V2, twin, RGB_MONO, AZURE_BODY_TRACKING])
        assert found == [RGB_MONO, KINECT_V2, AZURE_BODY_TRACKING]
        assert of_view.tolist() == [0, 1, 1, 0, 2] and not of_view.flags.writeable
    found, of_view = distinct_priors([twin, KINECT_V2])  # another sequence, another answer
    assert found == [KINECT_V2] and of_view.tolist() == [0, 0]
    types = ["azure_kinect", "rgb", "kinect_v2"]
    first = priors_of(types)
    first.append(KINECT_V2)  # the caller's own list: what is kept is not changed
    assert priors_of(types) == [AZURE_BODY_TRACKING, RGB_MONO, KINECT_V2]


def _fuse(types: list[str], settings: FusionSettings, thigh_m: float) -> np.ndarray:
    pipeline = FusionPipeline(settings)
    person = body()
    out = []
    for step in range(40):  # long enough for the online reference bone lengths
        views = []
        for k, sensor_type in enumerate(types):
            joints = person.copy()
            if k == 1:  # the second sensor's model puts the knees lower
                joints[[JointId.KNEE_LEFT, JointId.ANKLE_LEFT, JointId.FOOT_LEFT]] += (
                    0,
                    -thigh_m,
                    0,
                )
            states = np.full(JOINT_COUNT, 2, np.uint8)
            views.append(View(f"s{k}", k, joints, states, np.array([0.0, 1.0, 3.0]), sensor_type))
        out = pipeline.update(views, step / 30)
    assert len(out) == 1 and out[0].sources == tuple(f"s{k}" for k in range(len(types)))
    return out[0].joints


def test_pipeline_mixes_kinect_and_azure_views_of_one_person() -> None:
    settings = FusionSettings(
        tracking=TrackingSettings(min_frames=1),
        smoothing=SmoothingSettings(filter="none"),
        bones=BoneSettings(enforce=False),
    )
    off = dataclasses.replace(
        settings, weights=dataclasses.replace(settings.weights, sensor_priors=False)
    )
    same = _fuse(["kinect_v2", "azure_kinect"], off, 0.06)
    assert np.array_equal(same, _fuse(["kinect_v2", "kinect_v2"], settings, 0.06))
    mixed = _fuse(["kinect_v2", "azure_kinect"], settings, 0.06)
    assert np.isfinite(mixed).all()
    knee = JointId.KNEE_LEFT  # the Azure view's long thigh is its model, not noise: trusted more
    assert mixed[knee, 1] < same[knee, 1] - 0.005
