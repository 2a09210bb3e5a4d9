"""The agreement terms of the mirror cost: mean distances between the lateral joints of two
views, or of a view and the person's last fused skeleton, under both labellings.

:func:`lateral_terms` gives every pair's (2, 2) and every view's (2,) table at once for
:func:`skelfuse.fusion.mirror.choose_labellings`.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

LATERAL_JOINTS: Final = np.array([j for j in range(JOINT_COUNT) if MIRROR_PERMUTATION[j] != j])
"""The 20 joints that have a left or right side."""
LATERAL_SWAP: Final = np.array(
    [LATERAL_JOINTS.tolist().index(MIRROR_PERMUTATION[j]) for j in LATERAL_JOINTS]
)
"""Where each lateral joint's other side is in :data:`LATERAL_JOINTS`."""


def _joint_distances(a: FloatArray, b: FloatArray, out: FloatArray) -> None:
    """Per-joint distances between component-major arrays a, b: (3, ...) → ``out`` (...).

    ``sqrt((dx² + dy²) + dz²)``: the order ``np.linalg.norm`` sums three squares in (the same
    bits), without its reduction over a short axis.
    """
    dx = a[0] - b[0]
    dy = a[1] - b[1]
    dz = a[2] - b[2]
    np.sqrt(dx * dx + dy * dy + dz * dz, out=out)


def _mean_of_finite(d: FloatArray) -> FloatArray:
    """Mean over the last axis (the lateral joints) of the finite distances; 0 where none is.

    d: (..., 20) per-joint distances. Returns (...).
    """
    finite = np.isfinite(d)
    if finite.all():  # every joint seen in both: the same sums and divisions, fewer passes
        every: FloatArray = d.sum(-1) / np.intp(d.shape[-1])
        return every
    count = finite.sum(-1)
    total = np.where(finite, d, 0.0).sum(-1)
    result: FloatArray = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return result


def lateral_terms(
    views: FloatArray, first: IntArray, second: IntArray, references: FloatArray | None
) -> tuple[FloatArray, FloatArray]:
    """Mean lateral distances of each pair of views and of each view to its reference.

    The swapped labelling only reorders a view's lateral joints (:data:`LATERAL_SWAP`, an
    involution), so of a pair's four label combinations two are computed and the other two are
    the same per-joint distances reordered: (1, 1) is (0, 0) and (1, 0) is (0, 1), each read
    through the swap.

    Args:
        views: (N, 25, 3) metres; first, second: (K,) the views of each pair.
        references: (N, 25, 3) each view's person's reference skeleton (NaN: none), or None.

    Returns:
        pair: (K, 2, 2) mean distance under labellings (c_first, c_second);
        to_ref: (N, 2) mean distance of each labelling to the reference (0 without one).
    """
    # (3, N, 2, 20): component-major, each view's lateral joints as reported and swapped.
    lateral = np.empty((3, len(views), 2, len(LATERAL_JOINTS)))
    lateral[:, :, 0] = views[:, LATERAL_JOINTS].transpose(2, 0, 1)
    lateral[:, :, 1] = lateral[:, :, 0][:, :, LATERAL_SWAP]
    size = len(first)
    distances = np.empty((size * 4 + 2 * len(views), len(LATERAL_JOINTS)))
    pairs = distances[: size * 4].reshape(size, 2, 2, len(LATERAL_JOINTS))
    # The first view as reported against the second as reported and swapped: (0, 0), (0, 1).
    _joint_distances(lateral[:, first, :1], lateral[:, second], pairs[:, 0])
    pairs[:, 1] = pairs[:, 0, ::-1][:, :, LATERAL_SWAP]  # (1, 0), (1, 1) read through the swap
    if references is None:
        return _mean_of_finite(pairs), np.zeros((len(views), 2))
    ref = references[:, LATERAL_JOINTS].transpose(2, 0, 1)[:, :, None]  # (3, N, 1, 20)
    _joint_distances(lateral, ref, distances[size * 4 :].reshape(len(views), 2, -1))
    means = _mean_of_finite(distances)
    return means[: size * 4].reshape(size, 2, 2), means[size * 4 :].reshape(len(views), 2)
