"""Many persons' views stacked into one array, so every per-view step runs once per instant.

Views of P persons are stacked (N views; person ``person_of[i]``, its ``slot_of[i]``-th view);
per-person sums use (P, widest, ...) blocks padded after the real views with NaN views of weight
0, which leaves every sum and product as it is for one person alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.mirror_scores import slots
from skelfuse.fusion.view_factors import depth_noise_ratios, ray_weighted_mean
from skelfuse.fusion.views import View
from skelfuse.fusion.weighted import weighted_mean

FloatArray = npt.NDArray[np.float64]
_NO_POSITION = np.full(3, np.nan)


@dataclass(slots=True)
class ViewBatch:
    """The views of P persons stacked: person ``person_of[i]``'s ``slot_of[i]``-th view.

    joints: (N, 25, 3) float64 metres, world; states: (N, 25) uint8; sensors: (N, 3) metres.
    person_of, slot_of (N,) and starts (P + 1,) are shared read-only arrays.
    Per-person sums use (P, widest, ...) blocks padded after the real views (:meth:`pad`).
    depth_ratios: (N,) each view's noise along its sensor's ray over across it, None when all
    are 1 (fusion/view_factors.py: only ``rgb`` views have more).
    """

    views: list[View]
    counts: list[int]
    joints: FloatArray
    states: npt.NDArray[np.uint8]
    sensors: FloatArray
    person_of: npt.NDArray[np.intp]
    slot_of: npt.NDArray[np.intp]
    starts: npt.NDArray[np.intp]
    depth_ratios: FloatArray | None = None

    @classmethod
    def of(cls, clusters: list[list[View]], depth_noise: bool = True) -> ViewBatch:
        """The views of each person stacked; ``depth_noise``: look up each view's depth noise
        ratio (``FusionSettings.weights.sensor_priors``), else treat every view as isotropic."""
        counts = [len(cluster) for cluster in clusters]
        views = [view for cluster in clusters for view in cluster]
        places = slots(tuple(counts))  # cached per shape (read-only arrays): frames repeat
        # np.array on the lists: np.stack's values, a few times faster on these small arrays.
        return cls(
            views,
            counts,
            np.array([v.joints_world for v in views], dtype=np.float64),
            np.array([v.states for v in views]),
            np.array(
                [_NO_POSITION if v.sensor_position is None else v.sensor_position for v in views],
                dtype=np.float64,
            ),
            places.person_of,
            places.slot_of,
            places.starts,
            depth_noise_ratios([v.sensor_type for v in views]) if depth_noise else None,
        )

    @property
    def widest(self) -> int:
        return max(self.counts)

    def pad(self, values: FloatArray, fill: float) -> FloatArray:
        """(N, ...) per-view values as (P, widest, ...), ``fill`` after each person's views.

        When every person has the same number of views there is nothing to fill: the result is
        ``values`` reshaped (sharing its memory, float64); callers read it, never write to it.
        """
        widest = self.widest
        if widest * len(self.counts) == len(self.views):  # every person as wide as the widest
            same: FloatArray = np.ascontiguousarray(values, dtype=np.float64)
            return same.reshape(len(self.counts), widest, *values.shape[1:])
        padded = np.full((len(self.counts), widest, *values.shape[1:]), fill, np.float64)
        padded[self.person_of, self.slot_of] = values
        return padded

    def fuse(self, weights: FloatArray) -> FloatArray:
        """Step 6 on the batch: (P, 25, 3) each person's weighted mean (with each view's noise
        stretched along its sensor's ray for persons seen by a camera that guesses depth)."""
        joints, padded = self.pad(self.joints, np.nan), self.pad(weights, 0.0)
        fused = weighted_mean(joints, padded)
        if self.depth_ratios is None:
            return fused
        sensors, ratios = self.pad(self.sensors, np.nan), self.pad(self.depth_ratios, 1.0)
        return ray_weighted_mean(joints, padded, sensors, ratios, fused)

    def body_positions(self, fused: FloatArray) -> FloatArray:
        """(P, 3) where each person stands: fused SpineBase, else the mean of the views'."""
        fused_spine_ok = np.isfinite(fused[:, 0]).all(axis=-1, keepdims=True)
        if fused_spine_ok.all():  # every person's fused SpineBase known (the usual step)
            known: FloatArray = fused[:, 0].copy()
            return known
        spine = self.joints[:, 0]
        seen = np.isfinite(spine)
        sums = self.pad(np.where(seen, spine, 0.0), 0.0).sum(axis=1)
        counts = self.pad(seen.astype(np.float64), 0.0).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_spine = sums / counts
        positions: FloatArray = np.where(fused_spine_ok, fused[:, 0], mean_spine)
        return positions
