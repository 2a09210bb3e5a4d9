"""The confidence-weighted mean of each person's views as one loop, for a compiled kernel.

:func:`weighted_loop` is :func:`skelfuse.fusion.weighted.weighted_mean` written as scalar code:
:mod:`skelfuse.fusion.kernels` compiles it with numba. The same IEEE operations in the same
order, so the same bits: numpy's sums over the views axis start from 0 and add view after view
(not pairwise: the views axis is not the innermost), here too.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import jit

FloatArray = npt.NDArray[np.float64]


@jit
def weighted_loop(joints: FloatArray, weights: FloatArray, out: FloatArray) -> None:
    """Fill ``out`` (P, J, 3) with the weighted mean of ``joints`` (P, S, J, 3) under
    ``weights`` (P, S, J): a view counts where its point is finite and its weight positive;
    NaN where no view counts."""
    for p in range(joints.shape[0]):
        for j in range(joints.shape[2]):
            total = 0.0
            s0 = s1 = s2 = 0.0
            for s in range(joints.shape[1]):
                x0, x1, x2 = joints[p, s, j, 0], joints[p, s, j, 1], joints[p, s, j, 2]
                weight = weights[p, s, j]
                usable = (
                    math.isfinite(x0) and math.isfinite(x1) and math.isfinite(x2) and weight > 0
                )
                if not usable:
                    weight, x0, x1, x2 = 0.0, 0.0, 0.0, 0.0
                total += weight
                s0 += weight * x0
                s1 += weight * x1
                s2 += weight * x2
            if total <= 0:
                out[p, j, 0] = out[p, j, 1] = out[p, j, 2] = math.nan
            else:
                out[p, j, 0], out[p, j, 1], out[p, j, 2] = s0 / total, s1 / total, s2 / total
