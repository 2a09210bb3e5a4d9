"""Depth clouds for calibration: every agent asked at once for one cloud of what it sees.

Used by the ICP steps of ``skelfuse.server.calibration_runs``; the agents answer the
``depth_cloud`` request of :mod:`skelfuse.protocol.depth_cloud`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.protocol import depth_cloud
from skelfuse.protocol.errors import DecodeError
from skelfuse.server.errors import AgentRequestFailed

DEPTH_TIMEOUT_S = 20.0


class AgentCaller(Protocol):
    """Asks agents for things (``skelfuse.server.agent_requests.AgentRequests``)."""

    async def request(
        self, sensor_id: str, method: str, params: dict[str, Any], timeout_s: float
    ) -> Any: ...


async def capture_clouds(
    agents: AgentCaller, sensors: Sequence[str]
) -> dict[str, npt.NDArray[np.float64]]:
    """Each sensor's depth cloud, (N, 3) metres in its own frame, all asked at once.

    Raises:
        SensorUnavailable: a sensor went offline.
        AgentRequestFailed: an agent refused, timed out, or sent an invalid cloud.
    """

    async def one(sensor_id: str) -> tuple[str, npt.NDArray[np.float64]]:
        result = await agents.request(
            sensor_id, depth_cloud.METHOD, depth_cloud.encode_request(), DEPTH_TIMEOUT_S
        )
        try:
            return sensor_id, depth_cloud.decode_reply(result)
        except DecodeError as exc:
            raise AgentRequestFailed(f"sensor {sensor_id!r}: {exc}") from exc

    pairs = await asyncio.gather(*(one(s) for s in sensors))
    return dict(pairs)
