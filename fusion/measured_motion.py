"""The ``views`` predictor's measurement: how far each late body's person moved between the
late frame's capture and the instant, as that person's *on-time* views saw it (docs/fusion.md
§2, :mod:`skelfuse.fusion.extrapolation`).

Each on-time view is interpolated at both times; the difference is averaged over a person's
views joint by joint, over the views that have the joint Tracked at both times (an Inferred
joint is the sensor's guess, not a measurement), with left and right swapped for a view whose
mirror label differs from the late body's. One compiled loop does it per late body: per joint
coordinate, the differences where both times are Tracked, added view after view to 0.0 in the
person's view order, divided by their count; each late body's row straight from its person's
views, found by id. :func:`carried_worlds` then carries the late bodies by their scaled
measurement. Shapes: (25, 3) world metres per body.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.identity import ViewKey
from skelfuse.fusion.views import View
from skelfuse.fusion.world_views import SensorBodies, StackedRows
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, TrackingState

FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.intp]
_MIRROR = np.array(MIRROR_PERMUTATION, dtype=np.intp)
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
    out = np.empty((len(late), JOINT_COUNT, 3))
    _displacements_loop(
        plain(joints),
        plain(states, np.uint8),
        np.array([members[key] for key in keys], dtype=np.intp).reshape(-1, 2),
        np.array(late, dtype=np.intp).reshape(-1, 2),
        _MIRROR,
        _TRACKED,
        out,
    )
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


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now, off any latency-bound path."""
    joints = np.zeros((2, JOINT_COUNT, 3))
    states = np.full((2, JOINT_COUNT), _TRACKED, dtype=np.uint8)
    moved = _displacements([("s", 0)], {("s", 0): (1, True)}, [("s", 0)], joints, states)
    carried_worlds(joints[:1], np.ones(1), moved)


@jit
def _displacements_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    members: IndexArray,
    late: IndexArray,
    mirror: IndexArray,
    tracked: int,
    out: FloatArray,
) -> None:
    """:func:`_displacements` into ``out`` (L, 25, 3): ``members`` (K, 2) each on-time body's
    person id and mirror label (1: its left and right are swapped into the person's order of a
    body labelled 0); ``late`` (L, 2) each late body's person id, or −1 for nobody (its row is
    all NaN, as is the row of a person no on-time body is of), and its label (1: its row is
    swapped back); ``mirror``: the left-right permutation; ``tracked``: the state measured."""
    count = members.shape[0]
    own = np.empty(count, dtype=np.intp)  # the row's person's on-time bodies, in their order
    for row in range(late.shape[0]):
        person = late[row, 0]
        views = 0
        for k in range(count):
            if person >= 0 and members[k, 0] == person:
                own[views] = k
                views += 1
        for j in range(out.shape[1]):
            # The late body's joint j is the person's joint ``wanted`` in the order of a body
            # labelled 0; each view's own joint for it is swapped if the view is labelled 1.
            wanted = mirror[j] if late[row, 1] != 0 else j
            for c in range(3):
                total = 0.0
                seen = 0
                for v in range(views):
                    k = own[v]
                    source = mirror[wanted] if members[k, 1] != 0 else wanted
                    if states[k, source] != tracked or states[count + k, source] != tracked:
                        continue  # Inferred at either time: the sensor's guess, not measured
                    moved = joints[k, source, c] - joints[count + k, source, c]
                    if np.isfinite(moved):
                        total += moved
                        seen += 1
                out[row, j, c] = total / max(seen, 1) if seen > 0 else np.nan


def carried_worlds(
    worlds: FloatArray, scales: FloatArray, measured: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """Late bodies carried by their scaled measurement where it is known.

    Args:
        worlds: (B, 25, 3) the late bodies' newest joints, world metres.
        scales: (B,) each body's share of the measurement (its sensor's horizon over the
            furthest-late one's).
        measured: (B, 25, 3) metres, :func:`measured_from_arrays`' answer (NaN: not measured).

    Returns:
        The carried joints (B, 25, 3), ``worlds + scale × measured`` where that product is
        finite and ``worlds + 0.0`` elsewhere; where it is finite, (B, 25, 3); and whether it
        is finite at every joint of a body, (B,).
    """
    out = np.empty(worlds.shape)
    seen = np.empty(worlds.shape, dtype=np.bool_)
    whole = np.empty(worlds.shape[0], dtype=np.bool_)
    _carried_loop(plain(worlds), plain(scales), plain(measured), out, seen, whole)
    return out, seen, whole


@jit
def _carried_loop(
    worlds: FloatArray,
    scales: FloatArray,
    measured: FloatArray,
    out: FloatArray,
    seen: npt.NDArray[np.bool_],
    whole: npt.NDArray[np.bool_],
) -> None:
    """:func:`carried_worlds` into ``out``, ``seen`` and ``whole``."""
    for b in range(worlds.shape[0]):
        every = True
        for j in range(worlds.shape[1]):
            for c in range(3):
                carried = scales[b] * measured[b, j, c]
                finite = np.isfinite(carried)
                # + 0.0 where unknown, as numpy's where-then-add does (-0.0 becomes +0.0).
                out[b, j, c] = worlds[b, j, c] + (carried if finite else 0.0)
                seen[b, j, c] = finite
                every = every and finite
        whole[b] = every
