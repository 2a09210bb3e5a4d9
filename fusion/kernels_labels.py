"""The mirror labels' bookkeeping as loops, for a compiled kernel: each view's anatomical
evidence against its labelling, and the mirrored views swapped back in place.

:func:`evidence_loop` is :func:`skelfuse.fusion.label_scores.view_evidence` with its sum per
person, :func:`swap_loop` the swap in :func:`skelfuse.fusion.labels.label_views`, written as
scalar code: :mod:`skelfuse.fusion.kernels` compiles them with numba (the same bits: sums as
numpy's pairwise sum, copies as copies).

Imported only by :mod:`skelfuse.fusion.kernels_stages` when the kernels run; without numba
:func:`~skelfuse.fusion.kernels_jit.jit` leaves the functions plain Python (slow, same results).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import jit
from skelfuse.fusion.kernels_mirror import pairwise

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

_LARGEST = float(np.finfo(np.float64).max)
"""What ``np.nan_to_num`` puts in place of +inf."""


@jit
def evidence_loop(
    factors: FloatArray,
    mirrored: BoolArray,
    person_of: IntArray,
    per_view: FloatArray,
    evidence: FloatArray,
) -> None:
    """Fill ``per_view`` (N,) and ``evidence`` (P,) as ``label_scores.view_evidence`` and its
    sum per person (``np.bincount``: view after view from 0).

    factors: (N, 2, 25) range-of-motion factors as reported and swapped; mirrored: (N,) the
    labelling chosen; person_of: (N,) each view's person.
    """
    column = np.empty(factors.shape[2])
    out_of_range = np.empty(2)
    for p in range(len(evidence)):
        evidence[p] = 0.0
    for v in range(factors.shape[0]):
        for b in range(2):
            for m in range(len(column)):
                column[m] = 1.0 - factors[v, b, m]
            out_of_range[b] = pairwise(column, len(column))
        chosen = 1 if mirrored[v] else 0
        value = out_of_range[chosen] - out_of_range[1 - chosen]
        if value != value:  # np.nan_to_num
            value = 0.0
        elif value == math.inf:
            value = _LARGEST
        elif value == -math.inf:
            value = -_LARGEST
        per_view[v] = value
        evidence[person_of[v]] += value
