"""Association's trunk distances as one compiled loop (numba).

:func:`skelfuse.fusion.identity.trunk_distances` compares every view's midline joints with its
track's prediction at each step: a dozen numpy calls on (views, 5, 3) arrays, 28 µs for 24
views, nearly all of it the calls' fixed cost. Here one loop does the same IEEE operations in
the same order (``(x² + y²) + z²`` and its square root per joint, the distances summed joint
after joint, as numpy sums a last axis of five, divided by the count), so the same bits
(tests/unit/test_kernels_trunks.py). :func:`sticky_distances` does the usual step whole:
each view's midline joints and its track's prediction taken from the stacked joints in the
loop (``Track.predicted``'s step and sums), instead of two gathers and a dozen calls first.

As the other kernel modules: the loop runs only once :func:`warm_up` has compiled
it, so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import Warmed, jit, plain

FloatArray = npt.NDArray[np.float64]

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now; a no-op with the kernels off."""
    points = np.zeros((1, 5, 3))
    trunk_distances(points, points)
    index = np.zeros(1, dtype=np.intp)
    sticky_distances(np.zeros((1, 25, 3)), (np.zeros((1, 25, 3)), np.zeros((1, 3)), np.zeros(1)),
                     index, 0.0, index)  # fmt: skip
    warmed.done = True


def sticky_distances(
    views: FloatArray,
    tracks: tuple[FloatArray, FloatArray, FloatArray],
    rows: npt.NDArray[np.intp],
    t_s: float,
    trunk_joints: npt.NDArray[np.intp],
) -> FloatArray:
    """Each view's trunk distance to its track's prediction at ``t_s``: what
    ``trunk_distances(trunks, predicted[rows])`` gives on ``identity._trunks`` and
    ``identity._predicted_trunks`` (the same bits), without building either.

    Args:
        views: (N, 25, 3) metres, world; tracks: (T, 25, 3) each track's joints, (T, 3) its
            trunk velocity (m/s) and (T,) when it was last seen (seconds); rows: (N,) each
            view's track; trunk_joints: (K,) the midline joints.
    """
    joints, velocities, last_seen = tracks
    out = np.empty(views.shape[0])
    _sticky_loop(
        plain(views),
        (plain(joints), plain(velocities), plain(last_seen)),
        plain(rows, np.intp),
        float(t_s),
        plain(trunk_joints, np.intp),
        out,
    )
    return out


@jit
def _sticky_loop(  # pragma: no cover - compiled
    views: FloatArray,
    tracks: tuple[FloatArray, FloatArray, FloatArray],
    rows: npt.NDArray[np.intp],
    t_s: float,
    trunk_joints: npt.NDArray[np.intp],
    out: FloatArray,
) -> None:
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


def trunk_distances(a: FloatArray, b: FloatArray) -> FloatArray:
    """Per pair, the mean distance (metres) between the midline joints both have, ``inf``
    where they share fewer than two: a, b (M, K, 3) metres, the same shape → (M,) float64."""
    out = np.empty(a.shape[0])
    _distances_loop(plain(a), plain(b), out)
    return out


@jit
def _distances_loop(a: FloatArray, b: FloatArray, out: FloatArray) -> None:  # pragma: no cover
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
