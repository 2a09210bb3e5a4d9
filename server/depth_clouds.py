"""Depth clouds from agents: for calibration, every agent asked at once for one cloud of what it
sees (:func:`capture_clouds`); for viewers, each sensor's latest cloud on request, shared and
rate-limited (:class:`LatestClouds`, ``GET /api/sensors/{id}/cloud``).

Used by the ICP steps of ``skelfuse.server.calibration_runs`` and by
``skelfuse.server.routes_sensors``; the agents answer the ``depth_cloud`` request of
:mod:`skelfuse.protocol.depth_cloud`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.sensors import SensorState
from skelfuse.fusion.spaces import cloud_in_space
from skelfuse.protocol import depth_cloud
from skelfuse.protocol.errors import DecodeError
from skelfuse.server.clock import Clock
from skelfuse.server.errors import (
    AgentRequestFailed,
    CloudUnavailable,
    SensorUnavailable,
    ServerError,
)

DEPTH_TIMEOUT_S = 20.0


class AgentCaller(Protocol):
    """Asks agents for things (``skelfuse.server.agent_requests.AgentRequests``)."""

    async def request(
        self, sensor_id: str, method: str, params: dict[str, Any], timeout_s: float
    ) -> Any: ...


async def capture_clouds(
    agents: AgentCaller, sensors: Sequence[str], states: Mapping[str, SensorState] | None = None
) -> dict[str, npt.NDArray[np.float64]]:
    """Each sensor's depth cloud, (N, 3) metres in its own frame, all asked at once; with the
    hub's sensor ``states``, a moving sensor's in its tracking space (the frame its bodies are
    fused in: :func:`skelfuse.fusion.spaces.cloud_in_space`).

    Raises:
        SensorUnavailable: a sensor went offline.
        AgentRequestFailed: an agent refused, timed out, or sent an invalid cloud.
    """

    async def one(sensor_id: str) -> tuple[str, npt.NDArray[np.float64]]:
        result = await agents.request(
            sensor_id, depth_cloud.METHOD, depth_cloud.encode_request(), DEPTH_TIMEOUT_S
        )
        try:
            points = depth_cloud.decode_reply(result)
            if states is not None:
                points = cloud_in_space(states.get(sensor_id), result.get("t_capture_ns"), points)
        except (DecodeError, ValueError) as exc:
            raise AgentRequestFailed(f"sensor {sensor_id!r}: {exc}") from exc
        return sensor_id, points

    pairs = await asyncio.gather(*(one(s) for s in sensors))
    return dict(pairs)


VIEWER_TIMEOUT_S = 5.0
"""A viewer's cloud request gives up sooner than calibration's (a page waits for it)."""
VIEWER_MAX_AGE_S = 0.5
"""A cloud this young is served again instead of asking the agent: several viewers polling at
once cost the agent one capture per sensor and half second, not one each."""


@dataclass(frozen=True, slots=True)
class SensorCloud:
    """One sensor's depth cloud as captured: (N, 3) float64 metres in the sensor frame, the
    capture time on the server's clock (Unix seconds), and how many points the agent was asked
    for (a cloud asked with fewer cannot stand in for a larger request)."""

    points: npt.NDArray[np.float64]
    t_capture_s: float
    asked: int

    def at_most(self, max_points: int) -> npt.NDArray[np.float64]:
        """Up to ``max_points`` of the points, evenly spread over the cloud."""
        if len(self.points) <= max_points:
            return self.points
        step = -(-len(self.points) // max_points)  # ceil: every step-th point
        return self.points[::step][:max_points]


class LatestClouds:
    """Each sensor's latest depth cloud for viewers, asked of its agent on request.

    At most one request per sensor is in flight: concurrent callers wait for it (a per-sensor
    lock) and get its result, and a cloud (or refusal) younger than ``max_age_s`` is served
    again without asking. The agent subsamples to the asked ``max_points`` (protocol
    ``depth_cloud``), so nothing heavy runs here.
    """

    def __init__(
        self,
        agents: AgentCaller,
        clock_offset: Callable[[str], float | None],
        clock: Clock,
        max_age_s: float = VIEWER_MAX_AGE_S,
        timeout_s: float = VIEWER_TIMEOUT_S,
    ) -> None:
        """``clock_offset``: a sensor's server − agent clock offset (seconds), None unknown."""
        self._agents = agents
        self._clock_offset = clock_offset
        self._clock = clock
        self._max_age_s = max_age_s
        self._timeout_s = timeout_s
        self._locks: dict[str, asyncio.Lock] = {}
        self._latest: dict[str, tuple[float, SensorCloud | ServerError]] = {}
        self.requests_sent = 0
        """How many requests went to agents (tests and metrics)."""

    async def cloud(self, sensor_id: str, max_points: int) -> SensorCloud:
        """The sensor's newest cloud with at least ``max_points`` asked (``at_most`` trims it).

        Raises:
            SensorUnavailable: the sensor is offline (409).
            CloudUnavailable: the agent refused, timed out or sent an unusable cloud (503).
        """
        lock = self._locks.setdefault(sensor_id, asyncio.Lock())
        async with lock:  # one request in flight per sensor; the others wait for its answer
            kept = self._latest.get(sensor_id)
            if kept is not None and self._clock.monotonic() - kept[0] <= self._max_age_s:
                latest = kept[1]
                if isinstance(latest, ServerError):
                    raise latest
                if latest.asked >= max_points or len(latest.points) < latest.asked:
                    return latest  # asked for at least as much, or the agent had no more
            try:
                latest = await self._fetch(sensor_id, max_points)
            except SensorUnavailable:
                raise
            except ServerError as exc:
                self._latest[sensor_id] = (self._clock.monotonic(), exc)
                raise
            self._latest[sensor_id] = (self._clock.monotonic(), latest)
            return latest

    async def _fetch(self, sensor_id: str, max_points: int) -> SensorCloud:
        self.requests_sent += 1
        try:
            result = await self._agents.request(
                sensor_id,
                depth_cloud.METHOD,
                depth_cloud.encode_request(max_points),
                self._timeout_s,
            )
            points = depth_cloud.decode_reply(result, min_points=1)
        except AgentRequestFailed as exc:
            raise CloudUnavailable(f"no depth cloud now: {exc}") from exc
        except DecodeError as exc:
            raise CloudUnavailable(f"sensor {sensor_id!r} sent an unusable cloud: {exc}") from exc
        received_s = self._clock.time()
        stamp = result.get("t_capture_ns") if isinstance(result, Mapping) else None
        offset = self._clock_offset(sensor_id)
        t_capture = received_s
        if isinstance(stamp, int) and not isinstance(stamp, bool) and offset is not None:
            t_capture = stamp / 1e9 + offset  # the agent's capture stamp on the server's clock
        return SensorCloud(points, t_capture, max_points)
