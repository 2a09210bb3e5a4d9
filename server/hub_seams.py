"""What the hub's sessions need from the server around them, as protocols (the hub stays
socket-free): the recorder's tap and the server's requests to agents.
"""

from __future__ import annotations

from typing import Protocol

from skelfuse.protocol.wire import Response


class MessageTap(Protocol):
    """Sees every accepted hello and frame as received (the recorder, while a recording runs)."""

    def on_hello(self, sensor_id: str, payload: bytes, t_s: float) -> None: ...

    def on_frame(self, sensor_id: str, payload: bytes, t_s: float) -> None: ...


class PendingRequests(Protocol):
    """The server's requests to agents that wait for an answer
    (``skelfuse.server.agent_requests.AgentRequests``)."""

    def awaiting(self, sensor_id: str) -> bool:
        """True while a request to this sensor waits for its answer."""
        ...

    def resolve(self, sensor_id: str, response: Response) -> bool:
        """Hand over a response; False when no request of its id waits for this sensor."""
        ...

    def refuse(self, sensor_id: str, reason: str) -> None:
        """Fail the requests waiting on this sensor: its answer arrived but was refused."""
        ...
