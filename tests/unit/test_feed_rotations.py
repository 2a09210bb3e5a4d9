"""Joint rotations and hand states in the feed: opt-in rotations computed once per frame and
shared, forward kinematics from the message as sent, hands only where a sensor reports them,
and the default message unchanged."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import msgpack
import numpy as np
import pytest

from skelfuse.fusion.engine import FusedFrame
from skelfuse.geometry.quaternion import quaternion_multiply
from skelfuse.protocol.feed import frame_json, persons_json
from skelfuse.protocol.hands import HandConfidence, Hands, HandState
from skelfuse.protocol.skeleton import PARENTS
from skelfuse.recording.replay import replay
from skelfuse.server import broadcast
from skelfuse.server.broadcast import Broadcaster, Variant, encode_message
from tests.unit.test_joint_orientations import chain_known, forward_kinematics

TAKE = Path(__file__).resolve().parents[1] / "data" / "golden" / "take.sfrec"
HANDS = Hands(HandState.OPEN, HandState.LASSO, HandConfidence.HIGH, HandConfidence.LOW)


def _frames_with_people() -> list[FusedFrame]:
    frames = [f for f in replay(TAKE) if f.persons]
    assert len(frames) > 100
    return frames


def test_forward_kinematics_on_the_message_gives_its_joints_back_on_fused_motion() -> None:
    worst = 0.0
    checked = 0
    for frame in _frames_with_people()[::3]:
        orientations = broadcast.persons_orientations(frame.persons)
        message = json.loads(encode_message(frame_json(frame, False, 1.0, orientations), False))
        for person in message["persons"]:
            joints = np.array([np.nan * np.ones(3) if j is None else j for j in person["joints"]])
            local = np.array(person["local_rotations"])
            local /= np.linalg.norm(local, axis=1, keepdims=True)  # as sent: to 1e-5
            root = joints[0] if np.isfinite(joints[0]).all() else np.zeros(3)
            positions = forward_kinematics(root, local, np.array(person["rest_offsets"]))
            known = chain_known(joints)
            worst = max(worst, float(np.abs(positions - joints)[known].max()))
            checked += int(known.sum())
    assert checked > 2000
    assert worst < 0.005, f"{worst * 1000:.2f} mm"


def test_world_rotations_as_sent_are_parent_world_times_local() -> None:
    frame = _frames_with_people()[40]
    (person, *_) = persons_json(frame.persons, orientations=broadcast.persons_orientations(
        frame.persons))  # fmt: skip
    world = np.array(person["rotations"])
    local = np.array(person["local_rotations"])
    composed = quaternion_multiply(world[[max(p, 0) for p in PARENTS]], local)
    composed[0] = local[0]
    composed *= np.sign(composed[:, 3:] + 1e-12)
    np.testing.assert_allclose(composed, world, atol=5e-5)


def test_rotations_are_computed_once_per_frame_and_only_when_asked(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[int] = []
    real = broadcast.persons_orientations

    def counting(persons: object) -> object:
        calls.append(1)
        return real(persons)  # type: ignore[arg-type]

    monkeypatch.setattr(broadcast, "persons_orientations", counting)
    frame = _frames_with_people()[0]
    hub = Broadcaster()
    plain = hub.add(Variant(False, False), "a", 0.0)
    hub.publish(frame, 5.0, 0.0)
    assert calls == []  # nobody asked
    json_rotations = hub.add(Variant(False, False, True), "b", 0.0)
    packed_rotations = hub.add(Variant(True, True, True), "c", 0.0)
    also_json = hub.add(Variant(False, False, True), "d", 0.0)
    hub.publish(frame, 5.0, 0.0)
    assert calls == [1]
    default = json.loads(plain.take().payload)  # type: ignore[union-attr, arg-type]
    assert default == json.loads(encode_message(frame_json(frame, False, 5.0), False))
    assert "rotations" not in default["persons"][0]
    shared = json_rotations.take()
    assert shared is also_json.take()
    with_rotations = json.loads(shared.payload)  # type: ignore[union-attr, arg-type]
    packed = msgpack.unpackb(packed_rotations.take().payload)  # type: ignore[union-attr, arg-type]
    for persons in (with_rotations["persons"], packed["persons"]):
        assert [len(p["rotations"]) for p in persons] == [25] * len(frame.persons)
        assert len(persons[0]["local_rotations"][0]) == 4
        assert len(persons[0]["rest_offsets"][0]) == 3
    assert [s["rotations"] for s in hub.stats()] == [False, True, True, True]


def test_hand_states_are_sent_where_a_sensor_reports_them_only() -> None:
    frame = _frames_with_people()[0]
    before = encode_message(frame_json(frame, True, 2.0), False)
    assert "hands" not in before
    person = dataclasses.replace(frame.persons[0], hands=HANDS)
    view = dataclasses.replace(frame.raw[0], hands=HANDS)
    with_hands = dataclasses.replace(frame, persons=(person, *frame.persons[1:]),
                                     raw=(view, *frame.raw[1:]))  # fmt: skip
    message = json.loads(encode_message(frame_json(with_hands, True, 2.0), False))
    expected = {"left": {"state": "open", "confidence": "high"},
                "right": {"state": "lasso", "confidence": "low"}}  # fmt: skip
    assert message["persons"][0]["hands"] == expected
    assert message["raw"][0]["hands"] == expected
    assert all("hands" not in p for p in message["persons"][1:])
    message["persons"][0].pop("hands")
    message["raw"][0].pop("hands")
    assert message == json.loads(before)
