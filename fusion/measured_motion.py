"""The ``views`` predictor's measurement: how far each late body's person moved between the
late frame's capture and the instant, as that person's *on-time* views saw it (docs/fusion.md
§2, :mod:`skelfuse.fusion.extrapolation`).

Each on-time view is interpolated at both times; the difference is averaged over a person's
views joint by joint, over the views that have the joint Tracked at both times (an Inferred
joint is the sensor's guess, not a measurement), with left and right swapped for a view whose
mirror label differs from the late body's. Shapes: (25, 3) world metres per body.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_motion
from skelfuse.fusion.identity import ViewKey
from skelfuse.fusion.views import View
from skelfuse.fusion.world_views import SensorBodies, StackedRows
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, TrackingState

FloatArray = npt.NDArray[np.float64]
_MIRROR = np.array(MIRROR_PERMUTATION)
_UNSEEN = np.full((JOINT_COUNT, 3), np.nan)
"""A body none of whose joints the on-time views measured."""
_TRACKED = int(TrackingState.TRACKED)
"""Compared as a plain int: numpy compares a uint8 array with an IntEnum member 5× slower."""


def measured_displacements(
    late_keys: Iterable[ViewKey],
    members: Mapping[ViewKey, tuple[int, bool]],
    then: Mapping[ViewKey, View],
    now: Mapping[ViewKey, View],
) -> dict[ViewKey, FloatArray]:
    """How far each late body's person moved between the late frame's capture and the instant,
    as the on-time views of that person saw it, per joint: the mean over those views of (view
    at the instant − view at the capture), in the late body's joint order (left and right
    swapped for a view whose mirror label differs from the late body's), over the views where
    the joint is Tracked at both times.

    Args:
        late_keys: the late sensor's bodies (sensor id, tracking id).
        members: each body's (person id, mirror label) at the last step
            (:func:`~skelfuse.fusion.track_motion.track_members`).
        then: the on-time views interpolated at the late frame's capture time.
        now: the same views at the instant.

    Returns:
        (25, 3) metres per late body that has a person with an on-time view at both times, NaN
        where none of those views has the joint Tracked at both times; other bodies are absent.
    """
    keys = [k for k in now if k in then and k in members]
    if not keys:
        return {}
    joints = np.array([now[k].joints_world for k in keys] + [then[k].joints_world for k in keys])
    states = np.array([now[k].states for k in keys] + [then[k].states for k in keys])
    late_keys = list(late_keys)
    moved = _displacements(late_keys, members, keys, joints, states)
    present = {members[key][0] for key in keys}
    return {
        key: moved[row]
        for row, key in enumerate(late_keys)
        if members.get(key, (-1, False))[0] in present
    }


def _displacements(
    late_keys: list[ViewKey],
    members: Mapping[ViewKey, tuple[int, bool]],
    keys: list[ViewKey],
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
) -> FloatArray:
    """:func:`measured_displacements` of the on-time bodies ``keys`` (each with a person), their
    world joints and states at the instant (rows ``0..K-1``, (2K, 25, 3) and (2K, 25)) and at
    the late frame's capture (rows ``K..2K-1``): (L, 25, 3) metres, row by row ``late_keys``,
    all NaN for a body without a measurement."""
    unknown = (-1, False)  # a late body of nobody (person ids start at 1)
    late = [members.get(key, unknown) for key in late_keys]
    of_keys = [members[key] for key in keys]
    if kernels.enabled() and kernels_motion.warmed():  # the same bits in one loop
        return kernels_motion.person_displacements(
            joints,
            states,
            np.array(of_keys, dtype=np.intp).reshape(-1, 2),  # (person, label) rows
            np.array(late, dtype=np.intp).reshape(-1, 2),
        )
    persons = [person for person, _ in of_keys]
    labels = np.array([label for _, label in of_keys])
    # Each person's views, in their order (dicts keep it); persons numbered as they appear.
    group_index: dict[int, int] = {}
    group_of = [group_index.setdefault(person, len(group_index)) for person in persons]
    # Each late body's person's number (len(group_index): none) and whether it is swapped back.
    unseen = len(group_index)
    rows = [group_index.get(person, unseen) for person, _ in late]
    swapped = [at != unseen and swap for at, (_, swap) in zip(rows, late, strict=True)]
    count = len(keys)
    # An Inferred joint is the sensor's guess, not a measurement: its motion is not used.
    tracked = (states[:count] == _TRACKED) & (states[count:] == _TRACKED)
    moved_all = np.where(tracked[..., None], joints[:count] - joints[count:], np.nan)
    # Every view in the joint order of a body labelled False (a view labelled True swapped):
    # a body labelled True gets its person's mean swapped back (a permutation: the same sums).
    canonical = np.where(labels[:, None, None], moved_all[:, _MIRROR], moved_all)
    # Per person, its views in their order, padded with NaN (unseen) to the most views one has,
    # summed row after row: the sum over the person's rows alone, to the bit (np.add.reduceat
    # adds in another order).
    groups: list[list[int]] = [[] for _ in range(unseen)]
    for row, group in enumerate(group_of):
        groups[group].append(row)
    padded = np.full((len(groups), max(map(len, groups)), JOINT_COUNT, 3), np.nan)
    padded[
        [g for g, members_rows in enumerate(groups) for _ in members_rows],
        [w for members_rows in groups for w in range(len(members_rows))],
    ] = canonical[[row for members_rows in groups for row in members_rows]]
    finite = np.isfinite(padded)
    seen = finite.sum(axis=1)
    total = np.where(finite, padded, 0.0).sum(axis=1)
    means = np.where(seen > 0, total / np.maximum(seen, 1), np.nan)
    # Each late body's person's row (an all-NaN row past the persons' for none), gathered at
    # once; a body labelled True takes it swapped back.
    out: FloatArray = np.concatenate([means, _UNSEEN[None]])[rows]
    flipped = [row for row, swap in enumerate(swapped) if swap]
    if flipped:
        out[flipped] = out[flipped][:, _MIRROR]
    return out


def measured_from_arrays(
    newest: list[SensorBodies],
    members: Mapping[ViewKey, tuple[int, bool]],
    now: list[SensorBodies],
    then: list[SensorBodies],
    stacked: StackedRows | None = None,
) -> FloatArray:
    """:func:`measured_displacements` of the late bodies ``newest`` from the on-time sensors'
    bodies at the instant (``now``) and at the furthest-late sensor's capture (``then``), on
    their arrays: rows gathered by key instead of views looked up one by one (the same values).
    (B, 25, 3) metres in ``newest``'s body order, all NaN for a body without a measurement.

    ``stacked``: ``now``'s then ``then``'s world joints and states in one array each, row after
    row (what :func:`~skelfuse.fusion.world_views.resolve_with_rows` computed them in), or None
    to stack them here."""
    late_keys = [(b.sensor.sensor_id, i) for b in newest for i in b.bodies.tracking_ids]
    now_keys = [(b.sensor.sensor_id, i) for b in now for i in b.bodies.tracking_ids]
    if (
        now_keys
        # The same sensors with the same bodies at both times (compared sensor by sensor:
        # the same keys in the same order)
        and [(b.sensor.sensor_id, b.bodies.tracking_ids) for b in now]
        == [(b.sensor.sensor_id, b.bodies.tracking_ids) for b in then]
        and len(set(now_keys)) == len(now_keys)
        and all(key in members for key in now_keys)
    ):  # the usual instant: the same bodies at both times, each of a person: rows as they are
        if stacked is None:
            stacked = (
                np.concatenate([b.world for b in now] + [b.world for b in then]),
                np.concatenate([b.bodies.states for b in now] + [b.bodies.states for b in then]),
            )
        return _displacements(late_keys, members, now_keys, *stacked)
    then_keys = [(b.sensor.sensor_id, i) for b in then for i in b.bodies.tracking_ids]
    then_row = {key: row for row, key in enumerate(then_keys)}
    now_row = {key: row for row, key in enumerate(now_keys)}  # a key twice: the last row
    keys = [k for k in now_row if k in then_row and k in members]
    if not keys:
        return np.full((len(late_keys), JOINT_COUNT, 3), np.nan)
    rows = [now_row[k] for k in keys]
    rows += [len(now_keys) + then_row[k] for k in keys]
    joints = np.concatenate([b.world for b in now] + [b.world for b in then])[rows]
    states = np.concatenate([b.bodies.states for b in now] + [b.bodies.states for b in then])
    return _displacements(late_keys, members, keys, joints, states[rows])
