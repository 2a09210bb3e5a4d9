"""The online bone-length observation's per-view medians as one compiled loop (numba).

:func:`skelfuse.fusion.bones.observe_bone_lengths` takes, per person and bone, the median of
the lengths its views show: from good views only, and from any view with both ends Tracked.
In numpy that is a dozen calls on a padded (persons, 2, bones, views) array; here one loop
computes the same lengths (``((dx² + dy²) + dz²)`` then the square root, numpy's order of the
sum over the last axis) and the same medians (the mean of the middle two of the sorted finite
values: which sort puts them there does not change them), so the same bits
(tests/unit/test_kernels_observe.py).

The loop runs only once :func:`warm_up` has compiled it (or loaded it from numba's cache), so
no frame ever waits for a compilation; until then, and with the kernels off
(:func:`skelfuse.fusion.kernels.enabled`), the numpy code runs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import Warmed, jit, plain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now, off any latency-bound path; a no-op
    with the kernels off."""
    index = np.zeros(1, dtype=np.intp)
    bone_medians(np.zeros((1, 25, 3)), np.zeros((1, 25), np.uint8), np.zeros(1), index, 1,
                 (index, index), 2, 0.5)  # fmt: skip
    warmed.done = True


def bone_medians(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    cosines: FloatArray,
    person_of: IntArray,
    persons: int,
    ends: tuple[IntArray, IntArray],
    tracked: int,
    good_cos: float,
) -> FloatArray:
    """Per person and bone, the median length over its good views and over all its views.

    Args:
        joints: (N, 25, 3) every person's views, metres; states: (N, 25) tracking states;
            cosines: (N,) each view's facing cosine (a good view: finite and ≥ ``good_cos``);
            person_of: (N,) each view's person, < ``persons``; ends: each bone's parent and
            child joint, (B,) each; tracked: the state both ends need.

    Returns:
        (persons, 2, B) float64 metres: [.., 0] good views, [.., 1] any view; NaN where no
        view shows the bone.
    """
    parents, children = ends
    out = np.empty((persons, 2, len(parents)))
    _medians_loop(
        plain(joints),
        plain(states, np.uint8),
        plain(cosines),
        plain(person_of, np.intp),
        plain(parents, np.intp),
        plain(children, np.intp),
        int(tracked),
        float(good_cos),
        out,
    )
    return out


@jit
def _medians_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    cosines: FloatArray,
    person_of: IntArray,
    parents: IntArray,
    children: IntArray,
    tracked: int,
    good_cos: float,
    out: FloatArray,
) -> None:  # pragma: no cover - compiled; its numpy twin is the reference
    views, bones = joints.shape[0], parents.shape[0]
    lengths = np.empty((views, bones))
    good = np.empty(views, dtype=np.bool_)
    for i in range(views):
        c = cosines[i]
        good[i] = np.isfinite(c) and c >= good_cos
        for b in range(bones):
            parent, child = parents[b], children[b]
            length = np.nan
            if states[i, parent] == tracked and states[i, child] == tracked:
                dx = joints[i, child, 0] - joints[i, parent, 0]
                dy = joints[i, child, 1] - joints[i, parent, 1]
                dz = joints[i, child, 2] - joints[i, parent, 2]
                length = np.sqrt((dx * dx + dy * dy) + dz * dz)
                if not np.isfinite(length):
                    length = np.nan
            lengths[i, b] = length
    values = np.empty(max(views, 1))
    own = np.empty(max(views, 1), dtype=np.intp)  # the person's views, in their order
    for p in range(out.shape[0]):
        count_own = 0
        for i in range(views):
            if person_of[i] == p:
                own[count_own] = i
                count_own += 1
        for kind in range(2):
            for b in range(bones):
                count = 0
                for k in range(count_own):
                    i = own[k]
                    if kind == 0 and not good[i]:
                        continue
                    v = lengths[i, b]
                    if v != v:  # NaN: not shown
                        continue
                    j = count  # insertion into the sorted values so far
                    while j > 0 and values[j - 1] > v:
                        values[j] = values[j - 1]
                        j -= 1
                    values[j] = v
                    count += 1
                if count > 0:
                    out[p, kind, b] = (values[(count - 1) // 2] + values[count // 2]) / 2.0
                else:
                    out[p, kind, b] = np.nan
