"""The fused persons as apps receive them: sources sorted, each view's bit in joint_sources,
and the frozen object built without its __init__ the same as with it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skelfuse.fusion.views import FusedPerson, View, fused_persons
from skelfuse.protocol.skeleton import JOINT_COUNT

TRACKED = np.full(JOINT_COUNT, 2, dtype=np.uint8)


def _views(*sensor_ids: str) -> list[View]:
    return [View(s, k, np.zeros((JOINT_COUNT, 3)), TRACKED) for k, s in enumerate(sensor_ids)]


@pytest.mark.parametrize("widest", [3, 5])
def test_each_view_sets_its_sensors_bit_among_the_sorted_sources(widest: int) -> None:
    views = [_views("s2", "s0", "s1"), _views("b", "a")]
    carried = np.zeros((2, widest, JOINT_COUNT), dtype=bool)
    carried[0, 0, 3] = True  # s2: bit 2 (sources s0, s1, s2)
    carried[0, 1, [3, 4]] = True  # s0: bit 0
    carried[1, 1, 5] = True  # a: bit 0 (sources a, b)
    carried[1, 0, 6] = True  # b: bit 1
    flags = [[False, True, False], [False, False]]
    for _ in range(2):  # the second time from the kept layout
        first, second = fused_persons(
            [7, 9],
            [np.zeros((JOINT_COUNT, 3))] * 2,
            np.ones((2, JOINT_COUNT)),
            views,
            carried,
            flags,
        )
        assert first.sources == ("s0", "s1", "s2") and second.sources == ("a", "b")
        assert first.joint_sources[3] == 0b101 and first.joint_sources[4] == 0b001
        assert second.joint_sources[5] == 0b01 and second.joint_sources[6] == 0b10
        assert not first.joint_sources[0] and first.mirrored == ("s0",) and second.mirrored == ()
        assert (first.person_id, second.person_id) == (7, 9)
        assert first.views == tuple(views[0]) and first.hands is None


def test_the_person_is_the_frozen_object_its_init_builds() -> None:
    views = _views("s0", "s1")
    got = fused_persons(
        [3],
        [np.ones((JOINT_COUNT, 3))],
        np.full((1, JOINT_COUNT), 0.5),
        [views],
        np.ones((1, 2, JOINT_COUNT), dtype=bool),
        [[True, False]],
    )[0]
    expected = FusedPerson(
        3, np.ones((JOINT_COUNT, 3)), np.full(JOINT_COUNT, 0.5), ("s0", "s1"), tuple(views),
        np.full(JOINT_COUNT, 0b11), ("s0",), None,
    )  # fmt: skip
    for field in dataclasses.fields(FusedPerson):
        a, b = getattr(got, field.name), getattr(expected, field.name)
        assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, field.name
    with pytest.raises(dataclasses.FrozenInstanceError):
        got.person_id = 4  # type: ignore[misc]
