"""Time offsets of sources that share no clock, estimated from the motion itself.

Video files and cameras without timestamps start and run on clocks of their own: a frame
index says nothing about the instant it shows. Moving joints do: the same instant seen by two
calibrated cameras puts every landmark on its epipolar line. So a camera's **lag** is the shift
of its frames that brings its landmarks back onto the other views' epipolar lines.

API::

    sync = lags_from_epipolar(cameras, image_px, weights=None, *, rate_hz, max_lag_frames=8)
    sync.lag_frames   {name: float}  source frame t + lag shows what the reference shows at t
    sync.lag_s        {name: float}  the same in seconds: subtract from the source's timestamps
    sync.confidence   {name: float}  0..1; < 0.2: the motion did not pin the lag down
    sync.cost         {name: float}  at the lag found: median epipolar distance (px), or
                                     1 − speed correlation for lags_from_speed

    sync = lags_from_speed(tracks, *, rate_hz, max_lag_frames=8)    no calibration needed
    shifted(track (T, ...), sync.lag_frames[name]) -> the track on the reference's timeline

``image_px``: (V, T, J, 2) pixels as detected, NaN where not seen, V cameras at the same
nominal rate ``rate_hz``; ``weights`` (V, T, J) ≥ 0: a landmark of weight 0 (e.g. below a
visibility the caller trusts) is left out; the cost is a median, so other weights do not scale
it. The first camera is the reference (lag 0). Lags are found to sub-frame precision: the
frames are interpolated linearly at quarter-frame steps and the best step refined with a
parabola.

The epipolar method alternates: each camera's lag against all the others at their current
lags, then again, so one lagging camera does not pull the others' estimates. The cost is the
median (over frames and joints seen in both) of the symmetric epipolar distance: a robust
number that a few wrong landmarks do not move.

:func:`lags_from_speed` needs no calibration: it cross-correlates each source's joint speed
profile (each joint's speed about the body's centre over ±2 frames, divided by the body's
size in that source, so pixels and metres compare). It
is weaker: speeds seen from different sides differ (motion towards a camera barely moves in
its image), so use it only where the cameras are not calibrated, and check its confidence.

Where the lag goes: the calibration stores it per sensor (``SensorCalibration.lag_s``; ``skelfuse
calibration lag``), the live server and the offline replay subtract it from that sensor's
mapped times (``fusion/sensors.py``), and the offline mocap stamps each video's frames with it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.camera import Camera
from skelfuse.calibration.errors import InvalidInput, NotEnoughCorrespondences

FloatArray = npt.NDArray[np.float64]

STEP_FRAMES: Final = 0.25
ROUNDS: Final = 3
SPAN: Final = 2
"""Speeds for :func:`lags_from_speed` are displacements over ±SPAN frames."""
MIN_PAIRS: Final = 50
"""Fewer landmark pairs seen by both cameras at a candidate lag than this and it is not scored."""


@dataclass(frozen=True, slots=True)
class SyncEstimate:
    """Result of :func:`lags_from_epipolar` / :func:`lags_from_speed` (module docstring)."""

    lag_frames: dict[str, float]
    lag_s: dict[str, float]
    confidence: dict[str, float]
    cost: dict[str, float]


def lags_from_epipolar(
    cameras: Sequence[Camera],
    image_px: npt.ArrayLike,
    weights: npt.ArrayLike | None = None,
    *,
    rate_hz: float,
    max_lag_frames: float = 8.0,
) -> SyncEstimate:
    """Each camera's lag behind the first one, from epipolar geometry (module docstring).

    Raises:
        InvalidInput: fewer than 2 cameras, shapes other than (V, T, J, 2) / (V, T, J),
            negative weights, a rate or search range that is not positive.
        NotEnoughCorrespondences: a camera shares fewer than 50 landmark pairs with the others
            at every candidate lag (too short a clip, or nobody seen by both).
    """
    uv = _tracks(image_px, "image_px", last=2)
    names = [c.name for c in cameras]
    if len(cameras) != uv.shape[0] or len(cameras) < 2:
        raise InvalidInput(
            f"need at least 2 cameras and one (T, J, 2) track per camera; got {len(cameras)} "
            f"cameras and {uv.shape[0]} tracks"
        )
    w = _weights(weights, uv.shape[:-1])
    _check_rate(rate_hz, max_lag_frames)
    uv = np.where((w > 0)[..., None], uv, np.nan)
    rays = np.stack([_homogeneous(c.normalized(uv[i])) for i, c in enumerate(cameras)])
    focal = np.array([0.5 * (c.intrinsics.fx + c.intrinsics.fy) for c in cameras])
    essentials = {
        (a, b): _essential(cameras[a], cameras[b])
        for a in range(len(cameras))
        for b in range(len(cameras))
        if a != b
    }
    grid = np.arange(-max_lag_frames, max_lag_frames + 1e-9, STEP_FRAMES)
    lags = np.zeros(len(cameras))
    curves = np.full((len(cameras), len(grid)), np.nan)
    for _ in range(ROUNDS):
        for v in range(len(cameras)):
            others = [(u, shifted(rays[u], lags[u])) for u in range(len(cameras)) if u != v]
            for k, lag in enumerate(grid):
                moved = shifted(rays[v], lag)
                costs = [
                    _epipolar_cost(ray_u, moved, essentials[(u, v)], focal[u], focal[v])
                    for u, ray_u in others
                ]
                curves[v, k] = np.nanmean(costs) if np.isfinite(costs).any() else np.nan
            if not np.isfinite(curves[v]).any():
                raise NotEnoughCorrespondences(
                    f"camera {names[v]!r} shares fewer than {MIN_PAIRS} landmarks with the "
                    "others at every lag: a longer clip with the person in every view is needed"
                )
            lags[v] = _refined_minimum(grid, curves[v])
        lags -= lags[0]
    return _estimate(names, lags, grid, curves, rate_hz)


def lags_from_speed(
    tracks: npt.ArrayLike,
    *,
    names: Sequence[str],
    rate_hz: float,
    max_lag_frames: float = 8.0,
) -> SyncEstimate:
    """Each source's lag behind the first, from joint speed profiles (module docstring).

    Args:
        tracks: (V, T, J, D) joint positions per source (D = 2 pixels or 3 metres), NaN where
            missing; the same joints in the same order in every source.
        names: V source names.

    Raises:
        InvalidInput: fewer than 2 sources, names not matching, bad shapes, rate or range.
        NotEnoughCorrespondences: a source has fewer than 10 frames with speeds in common
            with the reference at every lag.
    """
    x = np.asarray(tracks, dtype=np.float64)
    if x.ndim != 4 or x.shape[0] < 2 or x.shape[0] != len(names):
        raise InvalidInput(
            f"tracks: expected (V >= 2, T, J, D) with one name per source, got {x.shape} and "
            f"{len(names)} names"
        )
    _check_rate(rate_hz, max_lag_frames)
    centre = np.nanmean(x, axis=2, keepdims=True)  # a median per axis would turn with the view
    size = np.nanmedian(np.linalg.norm(x - centre, axis=-1), axis=(1, 2))  # (V,)
    if not (np.isfinite(size) & (size > 0)).all():
        raise InvalidInput("tracks: a source has no finite joints to size the body by")
    # Body-relative (walking does not swamp the limbs) over ±SPAN frames (noise does not).
    relative = (x - centre) / size[:, None, None, None]
    speed = np.linalg.norm(relative[:, 2 * SPAN :] - relative[:, : -2 * SPAN], axis=-1)
    grid = np.arange(-max_lag_frames, max_lag_frames + 1e-9, STEP_FRAMES)
    curves = np.full((len(names), len(grid)), np.nan)
    lags = np.zeros(len(names))
    for v in range(1, len(names)):
        for k, lag in enumerate(grid):
            curves[v, k] = 1.0 - _correlation(speed[0], shifted(speed[v], lag))
        if not np.isfinite(curves[v]).any():
            raise NotEnoughCorrespondences(
                f"source {names[v]!r} has too few frames in common with {names[0]!r}"
            )
        lags[v] = _refined_minimum(grid, curves[v])
    curves[0] = 0.0
    return _estimate(list(names), lags, grid, curves, rate_hz, cost_scale=None)


def _tracks(array: npt.ArrayLike, name: str, *, last: int) -> FloatArray:
    x = np.asarray(array, dtype=np.float64)
    if x.ndim != 4 or x.shape[-1] != last:
        raise InvalidInput(f"{name}: expected shape (V, T, J, {last}), got {x.shape}")
    return x


def _weights(weights: npt.ArrayLike | None, shape: tuple[int, ...]) -> FloatArray:
    if weights is None:
        return np.ones(shape)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != shape:
        raise InvalidInput(f"weights: expected shape {shape}, got {w.shape}")
    if np.isnan(w).any() or (w < 0).any():
        raise InvalidInput("weights must be non-negative numbers")
    return w


def _check_rate(rate_hz: float, max_lag_frames: float) -> None:
    if not rate_hz > 0 or not max_lag_frames > 0:
        raise InvalidInput(
            f"rate_hz and max_lag_frames must be positive, got {rate_hz} and {max_lag_frames}"
        )


def _homogeneous(xy: FloatArray) -> FloatArray:
    return np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)


def _essential(a: Camera, b: Camera) -> FloatArray:
    """E with ``x_bᵀ·E·x_a = 0`` for normalised OpenCV rays of a and b at the same instant."""
    b_from_a = b.T_opencv_from_world @ np.linalg.inv(a.T_opencv_from_world)
    t = b_from_a[:3, 3]
    skew = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    essential: FloatArray = skew @ b_from_a[:3, :3]
    return essential


def shifted(track: FloatArray, lag: float) -> FloatArray:
    """``track`` (T, ...) resampled at frames ``t + lag`` (linear interpolation), NaN outside
    the recording: a camera's frames put on the reference's timeline with its lag."""
    frames = track.shape[0]
    t = np.arange(frames) + lag
    i0 = np.clip(np.floor(t).astype(int), 0, frames - 2)
    f = (t - i0).reshape((-1,) + (1,) * (track.ndim - 1))
    out = track[i0] * (1 - f) + track[i0 + 1] * f
    out[(t < 0) | (t > frames - 1)] = np.nan
    resampled: FloatArray = out
    return resampled


def _epipolar_cost(
    rays_a: FloatArray, rays_b: FloatArray, essential: FloatArray, focal_a: float, focal_b: float
) -> float:
    """Median symmetric epipolar distance (≈ pixels) over the landmarks both rays exist for."""
    line_b = rays_a @ essential.T  # epipolar lines in b
    line_a = rays_b @ essential  # epipolar lines in a
    algebraic = np.abs((line_b * rays_b).sum(axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        d_b = algebraic / np.linalg.norm(line_b[..., :2], axis=-1) * focal_b
        d_a = algebraic / np.linalg.norm(line_a[..., :2], axis=-1) * focal_a
    distance = 0.5 * (d_a + d_b)
    distance = distance[np.isfinite(distance)]
    return float(np.median(distance)) if distance.size >= MIN_PAIRS else float("nan")


def _correlation(a: FloatArray, b: FloatArray) -> float:
    """Mean over joints of the Pearson correlation of two (T, J) profiles (NaN-aware)."""
    both = np.isfinite(a) & np.isfinite(b)
    values = []
    for j in range(a.shape[1]):
        keep = both[:, j]
        if keep.sum() < 10:
            continue
        x, y = a[keep, j], b[keep, j]
        if x.std() == 0 or y.std() == 0:
            continue
        values.append(float(np.corrcoef(x, y)[0, 1]))
    return float(np.mean(values)) if values else float("nan")


def _refined_minimum(grid: FloatArray, curve: FloatArray) -> float:
    """The grid's best lag, refined by the parabola through it and its neighbours."""
    k = int(np.nanargmin(curve))
    if 0 < k < len(grid) - 1 and np.isfinite(curve[k - 1 : k + 2]).all():
        left, mid, right = curve[k - 1], curve[k], curve[k + 1]
        denominator = left - 2 * mid + right
        if denominator > 0:
            return float(grid[k] + 0.5 * (left - right) / denominator * STEP_FRAMES)
    return float(grid[k])


def _estimate(
    names: list[str],
    lags: FloatArray,
    grid: FloatArray,
    curves: FloatArray,
    rate_hz: float,
    cost_scale: float | None = 1.0,
) -> SyncEstimate:
    """Confidence: how much the cost rises two frames either side of the minimum, relative to
    the minimum (epipolar) or absolute (correlation); 0 when the minimum sits at the edge of
    the search range (the lag may lie beyond it)."""
    confidence: dict[str, float] = {}
    cost: dict[str, float] = {}
    for v, name in enumerate(names):
        curve = curves[v]
        if v == 0 or not np.isfinite(curve).any():
            confidence[name], cost[name] = 1.0, float(np.nanmin(curve)) if v else 0.0
            continue
        k = int(np.nanargmin(curve))
        best = float(curve[k])
        near = np.interp([grid[k] - 2.0, grid[k] + 2.0], grid, curve)
        rise = float(np.nanmean(near)) - best
        relative = rise / best if cost_scale is not None and best > 0 else rise
        at_edge = k in (0, len(grid) - 1)
        confidence[name] = 0.0 if at_edge else float(np.clip(relative / 0.2, 0.0, 1.0))
        cost[name] = best
    lag_frames = {name: float(lags[v]) for v, name in enumerate(names)}
    return SyncEstimate(
        lag_frames,
        {name: lag / rate_hz for name, lag in lag_frames.items()},
        confidence,
        cost,
    )
