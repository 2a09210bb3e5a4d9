"""Who may take a sensor id: the rule a ``hello`` is judged by when the id is already held.

One sensor id, one live connection. A ``hello`` for an id that another connection holds is
refused (``sensor_id_in_use``) while that connection is live: heard from within the liveness
time and, where the server can tell (:class:`PeerProbe`), still connected. With CurveZMQ the
second connection holds the sensor's own key, which proves only that it has the key: a copy of
it on a second PC, or an agent started twice, must not take the sensor over. The one case in
which it may is a restarted agent whose old connection is gone (it crashed without a ``bye``):
the probe sees that at once, so a restarted agent is back within a ``hello``, not after the
liveness time.
"""

from __future__ import annotations

from collections.abc import Callable

from skelfuse.fusion.sensors import SensorState
from skelfuse.protocol.wire import ErrorMessage

PeerProbe = Callable[[bytes], bool]
"""Tells whether a connection (ZeroMQ routing id) is still open (the server's socket)."""


def registration_refusal(
    sensor_id: str,
    existing: SensorState | None,
    routing_id: bytes,
    now_mono: float,
    liveness_s: float,
    authenticated: bool,
    probe: PeerProbe | None,
) -> ErrorMessage | None:
    """The ``error`` refusing a ``hello`` for ``sensor_id`` on ``routing_id``, or None to accept.

    Args:
        existing: what the server knows of the sensor (None: a new id).
        now_mono, liveness_s: monotonic seconds; the holder is live if heard within
            ``liveness_s``.
        authenticated: the connection proved it holds the sensor's CurveZMQ key.
        probe: whether a connection is still open; None when the server cannot tell (then a
            holder heard from recently counts as connected).
    """
    if (
        existing is None
        or not existing.connected
        or existing.routing_id == routing_id
        or now_mono - existing.last_heard_mono >= liveness_s
        or (probe is not None and not probe(existing.routing_id))
    ):
        return None
    hint = (
        "another live connection holds this sensor's key: run one agent per key"
        if authenticated
        else "give each agent its own --id"
    )
    return ErrorMessage(
        "sensor_id_in_use", f"sensor id {sensor_id!r} is in use by another live agent; {hint}"
    )
