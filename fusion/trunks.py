"""Trunks: association's measure of a person, and how a track's trunk moves.

Association (:mod:`skelfuse.fusion.identity`) decides whether two views, or a view and a
track's prediction, are the same person by the mean distance between the midline joints both
have: the same whatever a sensor thinks is left or right. One compiled loop computes it per
pair (``(x² + y²) + z²`` and its square root per joint, the distances summed joint after joint,
divided by the count); :func:`sticky_distances` takes each view's midline joints and its
track's prediction from the stacked skeletons in the loop, with no gathers first. After the
fusion, :func:`moved` keeps each track's skeleton and smooths its trunk velocity, the
prediction's slope, in one loop over the persons.

Shapes: (..., 5, 3) midline joints (:data:`TRUNK_JOINTS` order), metres, world frame.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JointId

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

TRUNK_JOINTS: Final = np.array(
    [JointId.SPINE_BASE, JointId.SPINE_MID, JointId.SPINE_SHOULDER, JointId.NECK, JointId.HEAD]
)
"""Joints on the body's midline: the same whatever a sensor thinks is left or right."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now, off any latency-bound path."""
    points = np.zeros((1, 5, 3))
    trunk_distances(points, points)
    index = np.zeros(1, dtype=np.intp)
    sticky_distances(np.zeros((1, 25, 3)), (np.zeros((1, 25, 3)), np.zeros((1, 3)), np.zeros(1)),
                     index, 0.0)  # fmt: skip
    joints = np.zeros((1, 25, 3))
    moved(joints, np.zeros(1), np.ones(1, bool), np.zeros((1, 3)), joints, 1.0, 3.0)


def trunk_distance(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Mean distance between the midline joints two skeletons both have (metres); ``inf``
    when they share fewer than two.

    Args:
        a, b: (25, 3) joints, metres, same frame; NaN where unknown.
    """
    pa = np.asarray(a, dtype=np.float64)[TRUNK_JOINTS]
    pb = np.asarray(b, dtype=np.float64)[TRUNK_JOINTS]
    return float(trunk_distances(pa, pb))


def trunk_distances(a: FloatArray, b: FloatArray) -> FloatArray:
    """Per pair, the mean distance (metres) between the midline joints both have (finite in
    both), ``inf`` where they share fewer than two.

    Args:
        a, b: (..., K, 3) midline joints, metres; their leading axes broadcast (views against
            tracks: (N, 1, K, 3) and (1, T, K, 3)).

    Returns:
        (...) float64, the broadcast leading shape.
    """
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    lead = a.shape[:-2]
    pairs = math.prod(lead)
    out = np.empty(pairs)
    _distances_loop(plain(a.reshape(pairs, *a.shape[-2:])), plain(b.reshape(pairs, *b.shape[-2:])),
                    out)  # fmt: skip
    return out.reshape(lead)


def sticky_distances(
    views: FloatArray,
    tracks: tuple[FloatArray, FloatArray, FloatArray],
    rows: IntArray,
    t_s: float,
) -> FloatArray:
    """Each view's trunk distance to its track's prediction at ``t_s`` (the track's joints
    moved by its velocity times ``min(max(t_s − last seen, 0), 0.5)``).

    Args:
        views: (N, 25, 3) metres, world; tracks: (T, 25, 3) each track's joints, (T, 3) its
            trunk velocity (m/s) and (T,) when it was last seen (seconds); rows: (N,) each
            view's track.

    Returns:
        (N,) float64 metres (``inf``: fewer than two midline joints in common).
    """
    joints, velocities, last_seen = tracks
    out = np.empty(views.shape[0])
    _sticky_loop(
        plain(views),
        (plain(joints), plain(velocities), plain(last_seen)),
        plain(rows, np.intp),
        float(t_s),
        plain(TRUNK_JOINTS, np.intp),
        out,
    )
    return out


@jit
def _sticky_loop(
    views: FloatArray,
    tracks: tuple[FloatArray, FloatArray, FloatArray],
    rows: IntArray,
    t_s: float,
    trunk_joints: IntArray,
    out: FloatArray,
) -> None:
    """:func:`sticky_distances` into ``out``."""
    joints, velocities, last_seen = tracks
    size = len(trunk_joints)
    a = np.empty((views.shape[0], size, 3))
    b = np.empty((views.shape[0], size, 3))
    for n in range(views.shape[0]):
        r = rows[n]
        # Track.predicted's step: min(max(t − last seen, 0), 0.5) as Python's max and min.
        dt = t_s - last_seen[r]
        if dt < 0.0:
            dt = 0.0
        if dt > 0.5:
            dt = 0.5
        for k in range(size):
            for c in range(3):
                a[n, k, c] = views[n, trunk_joints[k], c]
                b[n, k, c] = joints[r, trunk_joints[k], c] + velocities[r, c] * dt
    _distances_loop(a, b, out)


@jit
def _distances_loop(a: FloatArray, b: FloatArray, out: FloatArray) -> None:
    """:func:`trunk_distances` of (M, K, 3) pairs into ``out`` (M,)."""
    for m in range(a.shape[0]):
        total = 0.0
        count = 0
        for j in range(a.shape[1]):
            finite = True
            for k in range(3):
                if not (np.isfinite(a[m, j, k]) and np.isfinite(b[m, j, k])):
                    finite = False
            if not finite:
                continue
            dx = a[m, j, 0] - b[m, j, 0]
            dy = a[m, j, 1] - b[m, j, 1]
            dz = a[m, j, 2] - b[m, j, 2]
            total += np.sqrt((dx * dx + dy * dy) + dz * dz)
            count += 1
        out[m] = np.inf if count < 2 else total / max(count, 1)


def moved(
    joints: FloatArray,
    last_seen_s: FloatArray,
    fused_once: BoolArray,
    velocities: FloatArray,
    fused: FloatArray,
    t_s: float,
    max_speed_mps: float,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The tracks after a fusion at ``t_s``: the velocity's difference quotient of SpineBase
    (horizontal only), smoothed ``0.6 old + 0.4 new``, its speed ``√((x² + y²) + z²)`` clipped
    at ``max_speed_mps``; a joint kept where the fusion has none.

    Args:
        joints: (P, 25, 3) each track's skeleton before (world, metres); last_seen_s: (P,)
            when each was last fused (s); fused_once: (P,) whether it has been;
            velocities: (P, 3) its trunk velocity (m/s); fused: (P, 25, 3) this fusion,
            NaN where it has no joint; t_s: the instant (s); max_speed_mps: the speed clip.

    Returns:
        (P, 25, 3) the skeletons kept (the fused joint, the old one where there is none),
        (P, 3) the new velocities (the old ones where a track does not move), (P,) which
        tracks moved (fused before, within 0.5 s, with a SpineBase then and now).
    """
    count = joints.shape[0]
    kept = np.empty((count, joints.shape[1], 3))
    velocity = np.empty((count, 3))
    moving = np.empty(count, dtype=np.bool_)
    _move_loop(
        plain(joints),
        plain(last_seen_s),
        plain(fused_once, np.bool_),
        plain(velocities),
        plain(fused),
        float(t_s),
        float(max_speed_mps),
        kept,
        velocity,
        moving,
    )
    return kept, velocity, moving


@jit
def _move_loop(
    joints: FloatArray,
    last_seen_s: FloatArray,
    fused_once: BoolArray,
    velocities: FloatArray,
    fused: FloatArray,
    t_s: float,
    max_speed_mps: float,
    kept: FloatArray,
    velocity: FloatArray,
    moving: BoolArray,
) -> None:
    """:func:`moved` into ``kept``, ``velocity`` and ``moving``."""
    for p in range(joints.shape[0]):
        dt = t_s - last_seen_s[p]
        roots = True  # a SpineBase in both skeletons
        for k in range(3):
            roots = roots and np.isfinite(fused[p, 0, k]) and np.isfinite(joints[p, 0, k])
        moving[p] = fused_once[p] and dt > 0.0 and dt < 0.5 and roots
        if moving[p]:
            for k in range(3):
                new = 0.0 if k == 1 else (fused[p, 0, k] - joints[p, 0, k]) / dt
                velocity[p, k] = 0.6 * velocities[p, k] + 0.4 * new
            x, y, z = velocity[p, 0], velocity[p, 1], velocity[p, 2]
            speed = np.sqrt((x * x + y * y) + z * z)
            if speed > max_speed_mps:
                scale = max_speed_mps / speed
                for k in range(3):
                    velocity[p, k] = velocity[p, k] * scale
        else:
            for k in range(3):
                velocity[p, k] = velocities[p, k]
        for j in range(joints.shape[1]):
            for k in range(3):
                value = fused[p, j, k]
                kept[p, j, k] = value if np.isfinite(value) else joints[p, j, k]
