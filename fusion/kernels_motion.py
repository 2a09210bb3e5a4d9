"""The ``views`` predictor's measurement as one compiled loop (numba).

:func:`skelfuse.fusion.measured_motion.measured_from_arrays` averages, at every instant with a
late sensor, how far each person's on-time views moved between the late frame's capture and
the instant: in numpy some twenty calls on (views, 25, 3) arrays (a mask, a difference, a
mirror gather, a padded per-person stack and its sums, a gather per late body), 110 µs at
4 sensors × 6 people, nearly all of it the calls' fixed cost. Here one loop does the same IEEE
operations in the same order: per joint coordinate, the difference where both times are
Tracked, added view after view to 0.0 in the person's view order (numpy's sum over the stacked
views starts from 0.0 and adds them in that order; its padding adds 0.0, which changes no sum
that starts from 0.0), divided by the count of finite terms; each late body's row straight
from its person's views, found by id. So the same bits (tests/unit/test_kernels_motion.py).

As the other kernel modules: the loop runs only once :func:`warm_up` has compiled
it, so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import Warmed, jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, TrackingState

FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.intp]

_MIRROR = np.array(MIRROR_PERMUTATION, dtype=np.intp)
_TRACKED = int(TrackingState.TRACKED)

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now; a no-op with the kernels off."""
    joints = np.zeros((2, JOINT_COUNT, 3))
    states = np.full((2, JOINT_COUNT), _TRACKED, dtype=np.uint8)
    moved = person_displacements(
        joints, states, np.zeros((1, 2), dtype=np.intp), np.array([[0, 1]], dtype=np.intp)
    )
    carried_worlds(joints[:1], np.ones(1), moved)
    warmed.done = True


def person_displacements(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    members: IndexArray,
    late: IndexArray,
) -> FloatArray:
    """Per late body, its person's mean displacement over that person's on-time views.

    Args:
        joints: (2K, 25, 3) world metres: the K on-time bodies at the instant (rows ``0..K-1``)
            and at the late frame's capture (rows ``K..2K-1``).
        states: (2K, 25) tracking states, the same rows.
        members: (K, 2) each on-time body's person id and mirror label (1: its left and right
            are swapped into the person's order of a body labelled 0).
        late: (L, 2) each late body's person id, or −1 for nobody (its row is all NaN, as is
            the row of a person no on-time body is of), and its label (1: its row is swapped
            back).

    Returns:
        (L, 25, 3) metres, NaN where no view of the person has the joint Tracked at both times.
    """
    out = np.empty((late.shape[0], JOINT_COUNT, 3))
    _displacements_loop(
        plain(joints),
        plain(states, np.uint8),
        plain(members, np.intp),
        plain(late, np.intp),
        _MIRROR,
        _TRACKED,
        out,
    )
    return out


@jit
def _displacements_loop(  # pragma: no cover
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    members: IndexArray,
    late: IndexArray,
    mirror: IndexArray,
    tracked: int,
    out: FloatArray,
) -> None:
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
        measured: (B, 25, 3) metres, :func:`person_displacements`' answer (NaN: not measured).

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
def _carried_loop(  # pragma: no cover
    worlds: FloatArray,
    scales: FloatArray,
    measured: FloatArray,
    out: FloatArray,
    seen: npt.NDArray[np.bool_],
    whole: npt.NDArray[np.bool_],
) -> None:
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
