"""The server's hub: the agents' sessions, feeding the fusion engine what they send.

A :class:`FusionHub` is the :class:`~skelfuse.fusion.engine.FusionEngine` plus the sessions in
front of it: it decodes each raw message from an agent's connection (ZeroMQ routing id), judges
it (registration, a connection's CurveZMQ identity, replayed frames, a misbehaving connection's
rejection budget) and hands what is accepted to the engine. Socket-free so tests drive it
directly: ``skelfuse.server.ingest`` feeds it raw messages and sends back what it returns; the
fusion loop calls :meth:`FusionHub.fuse_step`. Every method whose logic depends on time takes the
time as an argument (``now_s``: wall clock, Unix seconds; ``now_mono``: monotonic seconds).

State changes from outside go through methods: :meth:`FusionHub.use_calibration` (a committed,
rolled back or imported calibration; a sensor whose pose it changes has its error learned
afresh), :meth:`FusionHub.start_tap` / :meth:`FusionHub.stop_tap` (a recording),
:meth:`FusionHub.attach_requests` (the server's requests to agents, whose responses the hub
routes back).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter

import numpy as np

from skelfuse import __version__
from skelfuse.calibration.store import Calibration
from skelfuse.fusion.engine import FusedFrame, FusionEngine, RollingStats
from skelfuse.fusion.sensors import SensorState
from skelfuse.fusion.settings import HubSettings
from skelfuse.fusion.spaces import SERVER_FEATURES
from skelfuse.protocol.constants import MAX_MESSAGE_BYTES, MAX_RESPONSE_BYTES
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.wire import (
    Bye,
    ErrorMessage,
    Frame,
    Heartbeat,
    Hello,
    Message,
    Response,
    Welcome,
    decode,
)
from skelfuse.server.hub_seams import MessageTap, PendingRequests
from skelfuse.server.registration import PeerProbe, registration_refusal
from skelfuse.server.rejection_budget import RejectionBudget

logger = logging.getLogger(__name__)


class FusionHub(FusionEngine):
    """The fusion engine with the agents' sessions in front: raw messages in, replies out."""

    def __init__(self, settings: HubSettings, calibration: Calibration | None = None) -> None:
        super().__init__(settings, calibration)
        self._by_routing: dict[bytes, str] = {}
        self.rejected_unregistered: Counter[str] = Counter()
        self.frame_arrived = asyncio.Event()
        self.started_s = time.time()
        self._requests: PendingRequests | None = None
        self._budget = RejectionBudget()
        self._probe: PeerProbe | None = None
        self._tap: MessageTap | None = None
        self.fusion_timing = RollingStats()
        """Seconds of compute per fusion step."""

    # --- state set from outside --------------------------------------------------------------

    def use_calibration(self, calibration: Calibration) -> None:
        """:meth:`FusionEngine.use_calibration`; each sensor whose pose it changes starts its
        learned error again from its prior (fusion/rig_errors.py): what fusion learned of a
        sensor where it stood says little of it where it stands now."""
        errors = self.pipeline.errors
        before = {s: self.pose_of(s)[0] for s in errors.sensor_ids}
        super().use_calibration(calibration)
        for sensor_id, pose in before.items():
            now = self.pose_of(sensor_id)[0]
            if (pose is None) != (now is None) or (
                pose is not None and now is not None and not np.array_equal(pose, now)
            ):
                errors.forget(sensor_id)

    def start_tap(self, tap: MessageTap) -> None:
        """Hand every accepted hello and frame to ``tap`` (a recording starts), replacing any."""
        self._tap = tap

    def stop_tap(self) -> None:
        """Stop handing messages to the tap (the recording stops)."""
        self._tap = None

    def attach_requests(self, requests: PendingRequests) -> None:
        """Route agents' ``response`` messages to ``requests`` (the server's request machinery);
        without it every response is rejected as unexpected."""
        self._requests = requests

    def attach_probe(self, probe: PeerProbe) -> None:
        """Ask ``probe`` whether a sensor's connection is still open before refusing a second
        one its id (server/registration.py); without it, recently heard counts as open."""
        self._probe = probe

    # --- sessions and messages ----------------------------------------------------------------

    def handle_message(
        self,
        routing_id: bytes,
        parts: list[bytes],
        now_s: float,
        now_mono: float,
        user_id: str | None = None,
    ) -> list[Message]:
        """Process one message from an agent; returns the replies to send back to it.

        ``user_id`` is the sensor id the connection authenticated as (CurveZMQ), if any: such a
        connection may register only that sensor id.
        """
        sensor = self._sensor_for(routing_id)
        if self._budget.exhausted(routing_id, now_mono):
            self._reject(sensor, "rate_limited")  # dropped unread: see _refuse
            return []
        if len(parts) != 1:
            self._refuse(sensor, "malformed", routing_id, now_mono)
            return []
        waiting = sensor is not None and self._awaiting(sensor.sensor_id)
        try:
            message = decode(parts[0], MAX_RESPONSE_BYTES if waiting else MAX_MESSAGE_BYTES)
        except DecodeError as exc:
            self._refuse(sensor, exc.reason, routing_id, now_mono)
            logger.debug("rejected message from %s: %s", sensor and sensor.sensor_id, exc)
            if (
                waiting
                and sensor is not None
                and self._requests is not None
                and len(parts[0]) > MAX_MESSAGE_BYTES
            ):
                # Only an answer may be this large: say why it will not come, rather than let
                # the request time out as if the agent had said nothing.
                self._requests.refuse(
                    sensor.sensor_id, f"its answer of {len(parts[0])} bytes was refused ({exc})"
                )
            return []
        if isinstance(message, Hello):
            return [self._hello(message, parts[0], routing_id, now_s, now_mono, user_id)]
        if sensor is None:
            return self._unregistered(routing_id, message, now_s, now_mono)
        sensor.last_heard_mono = now_mono
        sensor.connected = True
        match message:
            case Frame():
                if self.add_frame(sensor, message, now_s, now_mono) is not None:
                    return []
                if self._tap is not None:
                    self._tap.on_frame(sensor.sensor_id, parts[0], now_s)
                self.frame_arrived.set()
            case Heartbeat(echo_ns=echo) if echo is not None:
                sensor.round_trip.add(echo / 1e9, message.t_ns / 1e9, now_s)
            case Heartbeat():
                pass  # heard (above) is all a heartbeat without an echo tells
            case Bye():
                sensor.connected = False
                self._by_routing.pop(routing_id, None)
            case Response():
                if self._requests is None or not self._requests.resolve(sensor.sensor_id, message):
                    self._refuse(sensor, "unexpected_response", routing_id, now_mono)
            case _:
                self._refuse(sensor, "unexpected_type", routing_id, now_mono)
        return []

    def _hello(
        self,
        hello: Hello,
        payload: bytes,
        routing_id: bytes,
        now_s: float,
        now_mono: float,
        user_id: str | None,
    ) -> Message:
        """The reply to a ``hello`` (``payload``, its wire bytes): a welcome, or why not."""
        if user_id is not None and hello.sensor_id != user_id:
            self._refuse(None, "key_mismatch", routing_id, now_mono)
            return ErrorMessage(
                "key_mismatch",
                f"this agent's key belongs to sensor {user_id!r}, not "
                f"{hello.sensor_id!r}: run it with --id {user_id}",
            )
        reply = self._register(hello, routing_id, now_s, now_mono, user_id is not None)
        if isinstance(reply, Welcome) and self._tap is not None:
            self._tap.on_hello(hello.sensor_id, payload, now_s)
        return reply

    def _unregistered(
        self, routing_id: bytes, message: Message, now_s: float, now_mono: float
    ) -> list[Message]:
        """A message from a connection that holds no registration.

        A frame from a connection that was registered before (its sensor went offline, e.g.
        during a network pause) is the backlog the network held back: judged by its capture
        time with that sensor's clock offset, a stale one is counted ``stale`` against the
        sensor and dropped without an answer (a backlog of 70 frames must not draw 70 errors
        and re-registrations); anything else is told to say hello first.
        """
        sensor_id = self._by_routing.get(routing_id)
        known = self.sensors.get(sensor_id) if sensor_id is not None else None
        if (
            isinstance(message, Frame)
            and known is not None
            and known.routing_id == routing_id
            and known.frame_time_problem(message, now_s) == "stale"
        ):
            known.frames_rejected["stale"] += 1
            return []
        self._refuse(None, "not_registered", routing_id, now_mono)
        return [ErrorMessage("not_registered", "send hello first (did the server restart?)")]

    def _awaiting(self, sensor_id: str) -> bool:
        return self._requests is not None and self._requests.awaiting(sensor_id)

    def _sensor_for(self, routing_id: bytes) -> SensorState | None:
        """The registered, online sensor of this connection, if any."""
        sensor_id = self._by_routing.get(routing_id)
        sensor = self.sensors.get(sensor_id) if sensor_id is not None else None
        # An offline sensor keeps its connection's entry (to judge a backlog from it) but must
        # say hello again before anything from it counts.
        return sensor if sensor is not None and sensor.connected else None

    def _reject(self, sensor: SensorState | None, reason: str) -> None:
        if sensor is None:
            self.rejected_unregistered[reason] += 1
        else:
            sensor.frames_rejected[reason] += 1

    def _refuse(
        self, sensor: SensorState | None, reason: str, routing_id: bytes, now_mono: float
    ) -> None:
        """Count a protocol breach against the connection's budget (server/rejection_budget.py):
        past it, a flood costs a dict look-up per message, not a decode. A well-formed agent's
        timing (``stale``, ``future``, ``replayed_seq``) is judged with ``_reject`` instead."""
        self._reject(sensor, reason)
        if self._budget.note(routing_id, now_mono):
            peer = f"sensor {sensor.sensor_id}" if sensor else f"connection {routing_id.hex()}"
            logger.warning(
                "%s: %d messages refused in %.0f s (last: %s); the rest of that time its messages "
                "are dropped unread (rate_limited)", peer, self._budget.limit,
                self._budget.window_s, reason,
            )  # fmt: skip

    def _register(
        self,
        hello: Hello,
        routing_id: bytes,
        now_s: float,
        now_mono: float,
        authenticated: bool = False,
    ) -> Message:
        existing = self.sensors.get(hello.sensor_id)
        liveness_s = self.settings.heartbeat_interval_s * 3
        refusal = registration_refusal(
            hello.sensor_id, existing, routing_id, now_mono, liveness_s, authenticated, self._probe
        )
        if refusal is not None:
            self.rejected_unregistered["sensor_id_in_use"] += 1
            return refusal
        if existing is not None:
            self._by_routing.pop(existing.routing_id, None)
        self.register(hello, routing_id, now_mono)
        self._by_routing[routing_id] = hello.sensor_id
        logger.info(
            "sensor %s registered (%s, agent %s)",
            hello.sensor_id,
            hello.sensor_type,
            hello.agent_version,
        )
        interval_s = self.settings.heartbeat_interval_s
        return Welcome(__version__, interval_s, round(now_s * 1e9), SERVER_FEATURES)

    def check_liveness(self, now_mono: float) -> list[SensorState]:
        """Mark silent sensors offline (:meth:`FusionEngine.mark_silent_offline`); returns the
        sensors still online. An agent busy answering our request (a depth capture) gets until
        the request's own timeout before it counts as gone; an offline sensor's routing entry
        stays (see ``_unregistered``)."""
        return self.mark_silent_offline(now_mono, self._awaiting)

    # --- fusion ---------------------------------------------------------------------------

    def fuse_step(self, now_s: float) -> FusedFrame | None:
        """:meth:`FusionEngine.fuse_step`, its compute time kept in ``fusion_timing`` when it
        fused."""
        started = time.perf_counter()
        fused = super().fuse_step(now_s)
        if fused is not None:
            self.fusion_timing.add(time.perf_counter() - started)
        return fused
