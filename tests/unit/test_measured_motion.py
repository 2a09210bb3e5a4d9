"""The ``views`` predictor's measurement and carry against the rule, written below.

skelfuse.fusion.extrapolation through the function the live path calls (``_displacements``),
on random rigs: persons with one to twelve on-time views, mirrored views, Inferred and
untracked joints, unknown and infinite coordinates, zero and negative-zero displacements, late
bodies of nobody, of a person no on-time view sees, and labelled True; then ``carried_worlds``
against the carry in numpy.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import extrapolation
from skelfuse.fusion.identity import ViewKey
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, TrackingState


def _rig(
    seed: int,
) -> tuple[list[ViewKey], dict[ViewKey, tuple[int, bool]], list[ViewKey], np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    persons = int(rng.integers(1, 7))
    count = int(rng.integers(persons, persons * 12 + 1))
    keys = [(f"s{k}", int(rng.integers(0, 50))) for k in range(count)]
    person_ids = rng.permutation(100)[:persons] + 1
    members: dict[ViewKey, tuple[int, bool]] = {
        key: (int(person_ids[k % persons]), bool(rng.random() < 0.3)) for k, key in enumerate(keys)
    }
    then = rng.normal(0.0, 1.0, (count, JOINT_COUNT, 3)) * 10.0 ** rng.uniform(-3, 1)
    now = then + rng.normal(0.0, 0.05, then.shape)
    same = rng.random((count, JOINT_COUNT)) < 0.05
    now[same] = then[same]  # no motion: +0.0
    zero = rng.random((count, JOINT_COUNT)) < 0.05
    now[zero], then[zero] = -0.0, 0.0  # -0.0 − 0.0: a negative zero
    now[rng.random(now.shape) < 0.03] = np.nan
    if seed % 3 == 0:
        then[rng.random(then.shape) < 0.02] = np.inf
    joints = np.concatenate([now, then])
    states = rng.choice(
        np.array([TrackingState.TRACKED, TrackingState.INFERRED, TrackingState.NOT_TRACKED]),
        p=[0.85, 0.1, 0.05],
        size=(2 * count, JOINT_COUNT),
    ).astype(np.uint8)
    late = [(f"late{k}", k) for k in range(int(rng.integers(0, 8)))]
    for k, key in enumerate(late):
        if k % 4 == 1:
            continue  # nobody's body
        person = int(person_ids[k % persons]) if k % 4 != 2 else 1000  # 2: nobody seen
        members[key] = (person, bool(k % 2))
    return late, members, keys, joints, states


@pytest.mark.parametrize("seed", range(12))
def test_the_rule_body_by_body(seed: int) -> None:
    """One person's mean over its views, joint by joint, in the late body's order; a body
    without a measurement is all NaN."""
    late, members, keys, joints, states = _rig(seed)
    with np.errstate(invalid="ignore"):
        got = extrapolation._displacements(late, members, keys, joints, states)
    mirror = np.array(MIRROR_PERMUTATION)
    count = len(keys)
    for row, key in enumerate(late):
        person = members.get(key)
        views = [k for k, v in enumerate(keys) if person and members[v][0] == person[0]]
        if not views:
            assert np.isnan(got[row]).all()
            continue
        for j in range(JOINT_COUNT):
            terms = []
            for k in views:
                joint = mirror[j] if members[keys[k]][1] != person[1] else j
                both = states[k, joint] == 2 and states[count + k, joint] == 2
                if both:
                    terms.append(joints[k, joint] - joints[count + k, joint])
            for c in range(3):
                finite = [t[c] for t in terms if np.isfinite(t[c])]
                if finite:
                    assert got[row, j, c] == pytest.approx(np.mean(finite), rel=1e-9, abs=1e-12)
                else:
                    assert np.isnan(got[row, j, c])


@pytest.mark.parametrize("seed", range(20))
def test_the_carry_adds_the_scaled_measurement_where_it_is_known(seed: int) -> None:
    rng = np.random.default_rng(seed)
    bodies = int(rng.integers(1, 80))
    worlds = rng.normal(0.0, 2.0, (bodies, JOINT_COUNT, 3))
    worlds[rng.random(worlds.shape) < 0.05] = -0.0  # + 0.0 where unmeasured: +0.0
    measured = rng.normal(0.0, 0.02, worlds.shape)
    measured[rng.random(measured.shape) < 0.1] = np.nan
    measured[rng.random(measured.shape) < 0.02] = np.inf
    measured[rng.random(measured.shape) < 0.02] = -0.0
    if bodies > 1:
        measured[1] = 0.001  # a body measured at every joint
    scales = rng.uniform(0.0, 1.0, bodies)
    scales[rng.random(bodies) < 0.2] = 0.0  # 0 × inf: NaN, unmeasured
    with np.errstate(invalid="ignore"):
        carried = scales[:, None, None] * measured
    finite = np.isfinite(carried)
    got, seen, whole = extrapolation.carried_worlds(worlds, scales, measured)
    np.testing.assert_allclose(got, worlds + np.where(finite, carried, 0.0), rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(seen, finite)
    np.testing.assert_array_equal(whole, finite.all(axis=(1, 2)))
    assert whole.any() == (bodies > 1)
    assert not whole.all()  # some bodies have an unmeasured joint
    assert not np.signbit(got[~finite & (worlds == 0.0)]).any()  # -0.0 + 0.0: +0.0
