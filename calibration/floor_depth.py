"""Depth from the floor: a calibrated camera's body, scaled along its rays until a foot stands.

One camera fixes a body's shape and direction well and its distance poorly: a PnP placement of
metric landmarks (the ``mono`` source's) gets the distance from the body's size, which the
landmark model guesses. With the camera's pose and the floor known, the foot on the floor gives
the distance instead: the ray through that foot meets the floor at one point.

Here the whole camera-frame body is multiplied by one scale per frame, about the camera centre.
Every joint stays on its own ray, so the placement's image fit is kept exactly, and the contact
foot slides along its ray to the floor (raised by ``contact_height_m``: the foot landmarks are
on the shoe, not under the sole). The contact foot is the lowest foot point of the placed body;
a frame whose contact foot is hidden, above the camera's horizon, or would need an implausible
scale gets no floor scale (NaN). :func:`smooth_scales` takes a running median over frames and
carries the scale across frames without one (linear between the frames around them, held at
the ends): PnP's distance error comes mostly from the body's size, which does not change from
one frame to the next. Only where no frame at all had a foot on the floor does the placement
keep its own distance (scale 1.0).

Measured on the real clip against the four-view reference (bench/mono/floor_depth.py,
docs/benchmarks.md): absolute error 199 -> 161 mm on average over the four cameras, better on
three of them; the fourth, whose PnP distance was already within 5 cm, loses 8 mm. With the
feet hidden for 40 frames, carrying the scale across beats falling back to PnP there
(240 -> 210 mm in those frames). Both feet in the air (a jump) are not detected: the lower foot
is set on the floor (see ``scale_range``).

Frames: ``T_world_from_camera`` maps the camera frame (x right, y down, z forward, metres) to
the world; the floor is a :class:`~skelfuse.calibration.floor.FloorFit` in world coordinates
(``normal·p + d = 0``, normal up), so any world convention works (Y up or Z up).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import InvalidInput
from skelfuse.calibration.floor import FloorFit

FloatArray = npt.NDArray[np.float64]

DEFAULT_CONTACT_HEIGHT_M = 0.03
"""A planted foot's heel and toe landmarks above the floor: they sit on the shoe, not under the
sole (a typical sole and heel counter; a guess, not fitted to the test clip)."""

MEDIAPIPE_FEET: tuple[int, ...] = (29, 30, 31, 32)
"""Heels and foot tips of MediaPipe's 33 landmarks: the points that touch the floor (the ankles,
27 and 28, are a hand's width above it)."""


@dataclass(frozen=True, slots=True)
class FloorDepthSettings:
    """How the floor fixes a body's distance.

    ``contact_height_m``: height of a planted foot's landmarks above the floor (on the shoe's
    upper, not under the sole); ``min_visibility``: a contact foot seen less surely than this
    fixes nothing; ``scale_range``: scales outside it are rejected as a wrong contact (the
    placement's distance is rarely off by half; on the test clip every frame's scale was
    within 0.95-1.13, and a 30 cm jump seen from 1.9 m up would ask about 1.2);
    ``window_frames``: running-median length (odd; 1 = none); ``fill``: frames without a floor
    scale take it from the frames around them (``"carry"``) or keep the placement's distance
    (``"pnp"``).
    """

    contact_height_m: float = DEFAULT_CONTACT_HEIGHT_M
    min_visibility: float = 0.5
    scale_range: tuple[float, float] = (0.6, 1.6)
    window_frames: int = 9
    fill: Literal["carry", "pnp"] = "carry"


def floor_in_camera(T_world_from_camera: npt.ArrayLike, floor_world: FloorFit) -> FloorFit:
    """The world floor expressed in the camera's frame (normal up, ``d`` the camera's height).

    Raises:
        InvalidInput: not a finite (4, 4) matrix.
    """
    pose = np.asarray(T_world_from_camera, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise InvalidInput(f"T_world_from_camera must be a finite (4, 4) matrix, got {pose.shape}")
    normal = pose[:3, :3].T @ floor_world.normal
    d = float(floor_world.normal @ pose[:3, 3] + floor_world.d)
    return FloorFit(normal, d, floor_world.rmse_m, floor_world.inlier_count)


def contact_points(
    joints_cam: npt.ArrayLike, floor_cam: FloorFit, feet: Sequence[int] = MEDIAPIPE_FEET
) -> npt.NDArray[np.intp]:
    """Per frame, the index (into the joints) of the lowest foot point: the one on the floor.

    Args:
        joints_cam: (F, J, 3) placed joints in the camera frame, metres (NaN where unknown).
        floor_cam: the floor in the camera frame (:func:`floor_in_camera`).
        feet: joint indices that can touch the floor.

    Returns:
        (F,) joint indices; a frame whose feet are all unknown gets ``feet[0]``.
    """
    pts = np.asarray(joints_cam, dtype=np.float64)
    heights = floor_cam.height_of(pts[:, list(feet)])
    heights = np.where(np.isfinite(heights), heights, np.inf)
    lowest: npt.NDArray[np.intp] = np.asarray(feet, dtype=np.intp)[np.argmin(heights, axis=1)]
    return lowest


def floor_scales(
    joints_cam: npt.ArrayLike,
    floor_cam: FloorFit,
    *,
    visibility: npt.ArrayLike | None = None,
    feet: Sequence[int] = MEDIAPIPE_FEET,
    settings: FloorDepthSettings = FloorDepthSettings(),
) -> FloatArray:
    """Per frame, the scale about the camera centre that sets the contact foot on the floor.

    Args:
        joints_cam: (F, J, 3) placed joints in the camera frame, metres.
        floor_cam: the floor in the camera frame (:func:`floor_in_camera`).
        visibility: (F, J) in [0, 1], or None to trust every foot.
        feet: joint indices that can touch the floor.
        settings: contact height, visibility threshold, accepted scales.

    Returns:
        (F,) scales (1.0 = the placement as it is), NaN where the floor fixes nothing.

    Raises:
        InvalidInput: joints not (F, J, 3), or visibility not (F, J).
    """
    pts = np.asarray(joints_cam, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[2] != 3:
        raise InvalidInput(f"joints_cam must be (frames, joints, 3), got {pts.shape}")
    frames = np.arange(pts.shape[0])
    contact = contact_points(pts, floor_cam, feet)
    foot = pts[frames, contact]
    # s·foot on the raised floor: n·(s·foot) + d = h  ->  s = (h - d) / (n·foot).
    along_up = foot @ floor_cam.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        scales = (settings.contact_height_m - floor_cam.d) / along_up
    low, high = settings.scale_range
    usable = np.isfinite(scales) & (along_up < 0) & (scales >= low) & (scales <= high)
    if visibility is not None:
        vis = np.asarray(visibility, dtype=np.float64)
        if vis.shape != pts.shape[:2]:
            raise InvalidInput(f"visibility must be {pts.shape[:2]}, got {vis.shape}")
        usable &= vis[frames, contact] >= settings.min_visibility
    result: FloatArray = np.where(usable, scales, np.nan)
    return result


def smooth_scales(
    scales: npt.ArrayLike, window_frames: int, fill: Literal["carry", "pnp"] = "carry"
) -> FloatArray:
    """Running median of per-frame scales ignoring NaN, and frames whose window holds none
    filled: linearly between the nearest filled frames, held at the ends (``"carry"``), or 1.0
    (``"pnp"``). 1.0 everywhere when no frame has a scale.

    Args:
        scales: (F,) from :func:`floor_scales`.
        window_frames: odd window length in frames (1 = no smoothing).
        fill: how frames without a scale nearby are filled.

    Raises:
        InvalidInput: an even or non-positive window.
    """
    values = np.asarray(scales, dtype=np.float64).reshape(-1)
    if window_frames < 1 or window_frames % 2 == 0:
        raise InvalidInput(f"window_frames must be odd and >= 1, got {window_frames}")
    half = window_frames // 2
    padded = np.pad(values, half, constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, window_frames)
    known: npt.NDArray[np.bool_] = np.asarray(np.isfinite(windows).any(axis=1))
    # nanmedian warns on all-NaN rows: give those a placeholder, replaced just below.
    filled = np.where(known[:, None], windows, 1.0)
    result: FloatArray = np.where(known, np.nanmedian(filled, axis=1), 1.0)
    if fill == "carry" and known.any() and not known.all():
        frames = np.arange(values.size)
        result[~known] = np.interp(frames[~known], frames[known], result[known])
    return result


def place_on_floor(
    joints_cam: npt.ArrayLike,
    T_world_from_camera: npt.ArrayLike,
    floor_world: FloorFit,
    *,
    visibility: npt.ArrayLike | None = None,
    feet: Sequence[int] = MEDIAPIPE_FEET,
    settings: FloorDepthSettings = FloorDepthSettings(),
) -> tuple[FloatArray, FloatArray]:
    """The placed body with its distance from the floor: (F, J, 3) camera-frame joints, and the
    (F,) scales applied (1.0 where the floor fixed nothing nearby).

    Raises:
        InvalidInput: bad shapes or a non-finite camera pose.
    """
    pts = np.asarray(joints_cam, dtype=np.float64)
    floor_cam = floor_in_camera(T_world_from_camera, floor_world)
    raw = floor_scales(pts, floor_cam, visibility=visibility, feet=feet, settings=settings)
    scales = smooth_scales(raw, settings.window_frames, settings.fill)
    placed: FloatArray = pts * scales[:, None, None]
    return placed, scales


def level_camera_height(
    joints_cv: npt.ArrayLike,
    *,
    feet: Sequence[int] = MEDIAPIPE_FEET,
    contact_height_m: float = DEFAULT_CONTACT_HEIGHT_M,
) -> float:
    """A level camera's height above the floor, from a placed body's feet (no calibration).

    For one uncalibrated camera assumed level (optical axis horizontal, no roll): per frame the
    lowest foot point is on the floor, so the camera's height is how far below it that point
    is, plus ``contact_height_m``; the median over frames is returned.

    Args:
        joints_cv: (F, J, 3) placed joints, metres, OpenCV camera frame (+Y down); NaN rows
            where no body.

    Raises:
        InvalidInput: no frame with a finite foot point.
    """
    pts = np.asarray(joints_cv, dtype=np.float64)
    if pts.ndim != 3 or pts.shape[2] != 3:
        raise InvalidInput(f"joints_cv must be (frames, joints, 3), got {pts.shape}")
    below = pts[:, list(feet), 1]  # +Y down: the largest y is the lowest point
    known = np.isfinite(below).any(axis=1)
    if not known.any():
        raise InvalidInput("no frame has a foot point: the camera's height is unknown")
    lowest = np.nanmax(below[known], axis=1)
    return float(np.median(lowest)) + contact_height_m
