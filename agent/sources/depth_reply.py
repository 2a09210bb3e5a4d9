"""The ``depth_cloud`` answer of an SDK source (docs/protocol.md §6.5), shared by all of them.

A source turns its latest depth image into points in our sensor frame (metres, +X to the
sensor's left, +Y up, +Z forward); this module applies the request's limits and packs the reply.
"""

from __future__ import annotations

from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.constants import MAX_RESPONSE_BYTES

# One bin of N×3 float32; the server accepts answers up to MAX_RESPONSE_BYTES while it waits for
# them, and asks for at most 60 000 points.
DEFAULT_CLOUD_POINTS: Final = 20_000
MAX_CLOUD_POINTS: Final = min(60_000, (MAX_RESPONSE_BYTES - 4096) // 12)


def cloud_reply(
    points: npt.ArrayLike, params: dict[str, Any], **extra: object
) -> dict[str, object]:
    """The reply to a ``depth_cloud`` request.

    Args:
        points: (N, 3) metres in the sensor frame; rows with a non-finite value or z ≤ 0 (no
            depth) are dropped.
        params: the request's ``max_points`` (default 20 000, at most :data:`MAX_CLOUD_POINTS`)
            and ``max_range_m`` (default 5.0).
        extra: more fields for the reply (e.g. the device timestamp).
    """
    max_points = min(int(params.get("max_points", DEFAULT_CLOUD_POINTS)), MAX_CLOUD_POINTS)
    max_range = float(params.get("max_range_m", 5.0))
    cloud = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    cloud = cloud[np.isfinite(cloud).all(axis=1) & (cloud[:, 2] > 0)]
    cloud = cloud[np.linalg.norm(cloud, axis=1) <= max_range]
    if cloud.shape[0] > max_points:
        step = int(np.ceil(cloud.shape[0] / max_points))
        cloud = cloud[::step][:max_points]
    return {
        "frame": "sensor",
        "units": "m",
        "count": int(cloud.shape[0]),
        "points": np.ascontiguousarray(cloud, dtype="<f4").tobytes(),
        **extra,
    }
