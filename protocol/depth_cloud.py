"""The ``depth_cloud`` request and its reply (docs/protocol.md §6.5): one codec for both sides.

The server asks an agent for one depth frame as points in the agent's **sensor frame** (metres,
+X to the sensor's left, +Y up, +Z forward); calibration uses the clouds for ICP and the floor.

Request ``params`` (a msgpack map)::

    max_points   int    at most this many points (default 20 000, capped at MAX_POINTS)
    max_range_m  float  drop points farther than this from the sensor (default 5.0)

Reply ``result`` (a msgpack map)::

    points   bin    N × 3 little-endian float32, row-major (x0 y0 z0 x1 ...), metres
    count    int    N
    frame    str    "sensor"
    units    str    "m"
    ...             fields a source adds (capture time, device timestamp, intrinsics)

The server refuses a reply without a ``points`` bin, one whose length is not a multiple of 12,
and one with fewer than :data:`MIN_POINTS` finite points.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.constants import MAX_RESPONSE_BYTES
from skelfuse.protocol.errors import DecodeError

METHOD: Final = "depth_cloud"
DEFAULT_MAX_POINTS: Final = 20_000
MAX_POINTS: Final = min(60_000, (MAX_RESPONSE_BYTES - 4096) // 12)
"""The reply must fit a response the server waits for (MAX_RESPONSE_BYTES, with room for the
other fields)."""
MIN_POINTS: Final = 500
"""Fewer finite points than this cannot be registered: the sensor's view is likely blocked."""
DEFAULT_MAX_RANGE_M: Final = 5.0
_POINT_BYTES: Final = 12


@dataclass(frozen=True, slots=True)
class CloudRequest:
    """A decoded ``depth_cloud`` request: point budget and range (metres)."""

    max_points: int = DEFAULT_MAX_POINTS
    max_range_m: float = DEFAULT_MAX_RANGE_M


def encode_request(max_points: int = DEFAULT_MAX_POINTS) -> dict[str, object]:
    """The ``params`` of a ``depth_cloud`` request."""
    return {"max_points": max_points}


def decode_request(params: Mapping[str, Any]) -> CloudRequest:
    """Read a request's ``params``; a ``max_points`` above :data:`MAX_POINTS` is capped.

    Raises:
        DecodeError: ``max_points`` is not a positive integer (reason ``bad_field``), or
            ``max_range_m`` is not a positive finite number.
    """
    max_points = params.get("max_points", DEFAULT_MAX_POINTS)
    if isinstance(max_points, bool) or not isinstance(max_points, int) or max_points < 1:
        raise DecodeError("bad_field", f"max_points must be a positive integer, got {max_points!r}")
    max_range = params.get("max_range_m", DEFAULT_MAX_RANGE_M)
    if (
        isinstance(max_range, bool)
        or not isinstance(max_range, int | float)
        or not math.isfinite(max_range)
        or max_range <= 0
    ):
        raise DecodeError("bad_field", f"max_range_m must be a positive number, got {max_range!r}")
    return CloudRequest(min(max_points, MAX_POINTS), float(max_range))


def encode_reply(points: npt.ArrayLike, **extra: object) -> dict[str, object]:
    """The ``result`` of a ``depth_cloud`` reply.

    Args:
        points: (N, 3) metres, the sensor frame; sent as float32 exactly as given (filtering
            and subsampling are the source's job).
        extra: more fields for the reply (e.g. the capture time).

    Raises:
        ValueError: ``points`` cannot be reshaped to (N, 3).
    """
    cloud = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, 3))
    return {
        "frame": "sensor",
        "units": "m",
        "count": int(cloud.shape[0]),
        "points": cloud.tobytes(),
        **extra,
    }


def decode_reply(result: object, min_points: int = MIN_POINTS) -> npt.NDArray[np.float64]:
    """The points of a ``depth_cloud`` reply: (N, 3) float64, metres, the sensor frame, finite.

    Rows with a non-finite value are dropped. ``min_points``: fewer finite points are refused
    (default :data:`MIN_POINTS`, what ICP needs; a viewer that asked for fewer passes less).

    Raises:
        DecodeError: not a map with a ``points`` bin (reason ``bad_field``), a length that is
            not a multiple of 12 bytes (``bad_shape``), or fewer than ``min_points`` finite
            points (``out_of_range``).
    """
    if not isinstance(result, Mapping) or not isinstance(result.get("points"), bytes):
        raise DecodeError("bad_field", "the depth cloud has no 'points' bin")
    raw: bytes = result["points"]
    if len(raw) % _POINT_BYTES:
        raise DecodeError(
            "bad_shape", f"the depth cloud's {len(raw)} bytes are not N × 3 float32 values"
        )
    points = np.frombuffer(raw, dtype="<f4").reshape(-1, 3).astype(np.float64)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < min_points:
        raise DecodeError(
            "out_of_range",
            f"the depth cloud has only {len(points)} finite points (need {min_points}); "
            "is the sensor's view blocked?",
        )
    return points
