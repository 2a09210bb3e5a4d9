"""Requests from the server to agents (docs/protocol.md §6.5): send, await the response, time out.

The ingest socket is the only way out, so :class:`AgentRequests` is given the function that sends
one message to an agent's routing id. Answers come back through the hub, which hands every
``response`` message to :meth:`AgentRequests.resolve` (it is attached with
:meth:`skelfuse.server.hub.FusionHub.attach_requests`); the hub also asks
:meth:`AgentRequests.awaiting` whether a sensor owes an answer, to accept the larger response
size and to give a busy agent longer before it counts as gone.
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Awaitable, Callable
from typing import Any

from skelfuse.protocol.constants import MAX_RESPONSE_BYTES
from skelfuse.protocol.wire import Message, Request, Response
from skelfuse.server.errors import AgentRequestFailed, SensorUnavailable
from skelfuse.server.hub import FusionHub

SendFunction = Callable[[bytes, Message], Awaitable[None]]
"""Sends one message to the agent with this routing id (never blocks on a slow agent)."""


class _AnswerRefused(Exception):
    """The agent's answer arrived but the server refused it (too large, malformed)."""


class AgentRequests:
    """The requests in flight to agents, by request id."""

    def __init__(self, hub: FusionHub, send: SendFunction) -> None:
        self._hub = hub
        self._send = send
        self._pending: dict[int, tuple[str, asyncio.Future[Response]]] = {}
        self._ids = itertools.count(1)

    def awaiting(self, sensor_id: str) -> bool:
        """True while a request to this sensor waits for its answer."""
        return any(waiting_on == sensor_id for waiting_on, _ in self._pending.values())

    def resolve(self, sensor_id: str, response: Response) -> bool:
        """Hand a response from ``sensor_id`` to its waiting request.

        Returns False when no request of that id waits for this sensor (an unexpected response:
        the hub counts it as rejected).
        """
        pending = self._pending.get(response.request_id)
        if pending is None or pending[0] != sensor_id:
            return False
        if not pending[1].done():
            pending[1].set_result(response)
        return True

    def refuse(self, sensor_id: str, reason: str) -> None:
        """Fail every request waiting on ``sensor_id``: a message only an answer could be (over
        the 64 KiB limit of everything else) came from it and was refused for ``reason``."""
        for waiting_on, future in self._pending.values():
            if waiting_on == sensor_id and not future.done():
                future.set_exception(_AnswerRefused(reason))

    async def request(
        self, sensor_id: str, method: str, params: dict[str, Any], timeout_s: float
    ) -> Any:
        """Ask one agent to do something (e.g. capture a depth point cloud) and await its result.

        Raises:
            SensorUnavailable: the sensor is unknown or offline.
            AgentRequestFailed: the agent refused, failed, did not answer within
                ``timeout_s``, or its answer was refused (over 4 MiB, malformed).
        """
        sensor = self._hub.sensors.get(sensor_id)
        if sensor is None or not sensor.connected:
            raise SensorUnavailable(f"sensor {sensor_id!r} is not connected")
        request_id = next(self._ids)
        future: asyncio.Future[Response] = asyncio.get_running_loop().create_future()
        self._pending[request_id] = (sensor_id, future)
        try:
            await self._send(sensor.routing_id, Request(request_id, method, params))
            response = await asyncio.wait_for(future, timeout=timeout_s)
        except TimeoutError as exc:
            raise AgentRequestFailed(
                f"sensor {sensor_id!r} did not answer {method!r} within {timeout_s:.0f} s"
            ) from exc
        except _AnswerRefused as exc:
            raise AgentRequestFailed(
                f"sensor {sensor_id!r} answered {method!r}, but {exc} (docs/protocol.md §4: "
                f"answers up to {MAX_RESPONSE_BYTES} bytes)"
            ) from exc
        finally:
            self._pending.pop(request_id, None)
        if not response.ok:
            raise AgentRequestFailed(f"sensor {sensor_id!r} refused {method!r}: {response.error}")
        return response.result
