"""The ``depth_cloud`` answer of an SDK source (docs/protocol.md §6.5), shared by all of them.

A source turns its latest depth image into points in our sensor frame (metres, +X to the
sensor's left, +Y up, +Z forward); this module keeps the points the request asks for and packs
the reply with the protocol's codec (:mod:`skelfuse.protocol.depth_cloud`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.depth_cloud import decode_request, encode_reply


def cloud_reply(
    points: npt.ArrayLike, params: dict[str, Any], **extra: object
) -> dict[str, object]:
    """The reply to a ``depth_cloud`` request.

    Args:
        points: (N, 3) metres in the sensor frame; rows with a non-finite value or z ≤ 0 (no
            depth) are dropped, and so are points beyond the request's ``max_range_m``; what is
            left is subsampled evenly to the request's ``max_points``.
        params: the request's params (``protocol.depth_cloud.decode_request``).
        extra: more fields for the reply (e.g. the device timestamp).

    Raises:
        DecodeError: bad params (the agent answers with a refusal).
    """
    request = decode_request(params)
    cloud = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    cloud = cloud[np.isfinite(cloud).all(axis=1) & (cloud[:, 2] > 0)]
    cloud = cloud[np.linalg.norm(cloud, axis=1) <= request.max_range_m]
    if cloud.shape[0] > request.max_points:
        step = int(np.ceil(cloud.shape[0] / request.max_points))
        cloud = cloud[::step][: request.max_points]
    return encode_reply(cloud, **extra)
