"""One limb's left and right labels put right in a view whose other labels are right.

The mirror step (:mod:`skelfuse.fusion.labels`) decides whole views: a body seen from behind
reported left for right. A tracker can also swap a single pair of limbs, most often side-on,
where one arm or leg hides the other: the left arm reported where the right arm is, the rest
of the body right. Such a view's arm is 30–50 cm off while its trunk agrees with every other
view, so no whole-view decision sees it, and weighting can only make it count less.

Here each view's arms and legs are compared with where the other views put them (their
weighted mean without the view): if the view's left limb is much nearer the reference's right
one and its right limb nearer the left one, the pair is swapped back (joints and tracking
states). A person seen by two views cannot tell by them alone which one is swapped: a view is
swapped back only if it is swapped against the other view *and* against the person's track,
so a track that went wrong once cannot turn views that agree with each other. A person seen
once is left alone. "Much nearer": the swapped labelling's squared distance under
:data:`SWAP_RATIO` of the reported one's and better by at least :data:`MIN_GAIN_M` per joint, so
that limbs close together (legs side by side) are left alone: there the labels matter little
and the evidence is weak.

Shapes: N views of P persons stacked as :class:`skelfuse.fusion.weigh.ViewBatch` stacks them,
25 joints; metres, world frame; labels of whole views already corrected. The loop is compiled
with numba (:func:`limb_swap_loop`).
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.rig_errors import left_out
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JointId

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]
J = JointId

LIMBS: Final = np.array(
    [
        [J.ELBOW_LEFT, J.WRIST_LEFT, J.HAND_LEFT, J.HAND_TIP_LEFT, J.THUMB_LEFT],
        [J.ELBOW_RIGHT, J.WRIST_RIGHT, J.HAND_RIGHT, J.HAND_TIP_RIGHT, J.THUMB_RIGHT],
        [J.KNEE_LEFT, J.ANKLE_LEFT, J.FOOT_LEFT, -1, -1],
        [J.KNEE_RIGHT, J.ANKLE_RIGHT, J.FOOT_RIGHT, -1, -1],
    ],
    dtype=np.intp,
)
"""The limbs below shoulders and hips, left then right for arms then legs (−1: padding)."""
SWAP_RATIO: Final = 0.25
"""The swapped labelling must fit at least this much better (its squared distance ratio)."""
MIN_GAIN_M: Final = 0.1
"""...and bring each of the limb pair's joints this much nearer on average (metres, RMS)."""


def swap_limbs(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    weights: FloatArray,
    starts: IntArray,
    tracks: tuple[FloatArray, BoolArray],
) -> BoolArray:
    """Swap back each view's arms or legs whose labels are swapped (module docstring), in
    place in ``joints`` (N, 25, 3) and ``states`` (N, 25).

    Args:
        weights: (N, 25) the views' fusion weights (the reference is their weighted mean).
        starts: (P + 1,) each person's first view, then N.
        tracks: (P, 25, 3) each person's track skeleton and (P,) whether it has one.

    Returns:
        (N, 2) which views' arms (column 0) and legs (column 1) were swapped.
    """
    out = np.zeros((len(joints), 2), dtype=np.bool_)
    limb_swap_loop(
        joints, states, plain(weights), plain(starts, np.intp), plain(tracks[0]),
        plain(tracks[1], np.bool_), LIMBS, out,
    )  # fmt: skip
    return out


@jit
def limb_swap_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    weights: FloatArray,
    starts: IntArray,
    track: FloatArray,
    tracked: BoolArray,
    limbs: IntArray,
    out: BoolArray,
) -> None:
    """:func:`swap_limbs`' loop: fill ``out`` (N, 2) and swap in place."""
    others = np.empty((2, limbs.shape[1], 3))
    tracked_limbs = np.empty((2, limbs.shape[1], 3))
    for p in range(len(starts) - 1):
        lo, hi = starts[p], starts[p + 1]
        if hi - lo < 2 or (hi - lo == 2 and not tracked[p]):
            continue
        for k in range(lo, hi):
            for pair in range(2):
                left, right = limbs[2 * pair], limbs[2 * pair + 1]
                for side in range(2):
                    chain = left if side == 0 else right
                    for i in range(len(chain)):
                        j = chain[i]
                        if j >= 0:  # the others' mean: the view less its residual to it
                            residual = left_out(joints, weights, weights, lo, hi, k, j)[1]
                            for c in range(3):
                                others[side, i, c] = joints[k, j, c] - residual[c]
                            tracked_limbs[side, i] = track[p, j]
                swap = _swapped(joints[k], left, right, others)
                if tracked[p]:
                    swap = swap and _swapped(joints[k], left, right, tracked_limbs)
                if swap:
                    out[k, pair] = True
                    for i in range(len(left)):
                        a, b = left[i], right[i]
                        if a < 0:
                            continue
                        for c in range(3):
                            joints[k, a, c], joints[k, b, c] = joints[k, b, c], joints[k, a, c]
                        states[k, a], states[k, b] = states[k, b], states[k, a]


@jit
def _swapped(view: FloatArray, left: IntArray, right: IntArray, reference: FloatArray) -> bool:
    """Whether ``view``'s (25, 3) limbs ``left`` and ``right`` fit ``reference`` (2, L, 3: the
    left and right limb) swapped much better than as reported."""
    kept = crossed = 0.0
    count = 0
    for i in range(len(left)):
        a, b = left[i], right[i]
        if a < 0:
            continue
        va, vb, ra, rb = view[a], view[b], reference[0, i], reference[1, i]
        pair = va[0] + va[1] + va[2] + vb[0] + vb[1] + vb[2] + ra[0] + ra[1] + ra[2]
        if not math.isfinite(pair + rb[0] + rb[1] + rb[2]):
            continue
        for c in range(3):
            kept += (va[c] - ra[c]) ** 2 + (vb[c] - rb[c]) ** 2
            crossed += (va[c] - rb[c]) ** 2 + (vb[c] - ra[c]) ** 2
        count += 1
    if count == 0:
        return False
    return crossed < SWAP_RATIO * kept and kept - crossed > 2 * count * MIN_GAIN_M**2


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loop now."""
    joints = np.zeros((2, 25, 3))
    swap_limbs(
        joints, np.zeros((2, 25), np.uint8), np.ones((2, 25)), np.array([0, 2], dtype=np.intp),
        (np.zeros((1, 25, 3)), np.ones(1, dtype=np.bool_)),
    )  # fmt: skip
