"""The server's state machine: sessions, frames, calibration and the fusion step.

Socket-free so it can be driven directly in tests: ``skelfuse.server.ingest`` feeds it raw
messages and sends back what it returns; the fusion loop calls :meth:`FusionHub.fuse_step`.
Every method whose logic depends on time takes the time as an argument (``now_s``: wall clock,
Unix seconds; ``now_mono``: monotonic seconds), so tests drive it with a clock of their own.

State changes from outside go through methods: :meth:`FusionHub.use_calibration` (a committed,
rolled back or imported calibration), :meth:`FusionHub.start_tap` / :meth:`FusionHub.stop_tap`
(a recording), :meth:`FusionHub.attach_requests` (the server's requests to agents, whose
responses the hub routes back).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from dataclasses import dataclass

from skelfuse import __version__
from skelfuse.calibration.store import Calibration
from skelfuse.fusion import kernels
from skelfuse.fusion.alignment import Alignment, live_timings
from skelfuse.fusion.drift import DriftMonitor
from skelfuse.fusion.extrapolation import late_motions, views_with_late
from skelfuse.fusion.hub_seams import MessageTap, PendingRequests
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.fusion.registration import PeerProbe, registration_refusal
from skelfuse.fusion.rejection_budget import RejectionBudget
from skelfuse.fusion.sensor_rows import sensor_rows
from skelfuse.fusion.sensors import SensorState, calibrated_lag_s, new_sensor
from skelfuse.fusion.settings import HubSettings
from skelfuse.fusion.spaces import SERVER_FEATURES, resolve_pose
from skelfuse.fusion.stats import RollingStats
from skelfuse.fusion.views import FusedPerson, View
from skelfuse.protocol.constants import MAX_MESSAGE_BYTES, MAX_RESPONSE_BYTES
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.transform import Matrix4
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

logger = logging.getLogger(__name__)

OFFLINE_AFTER_INTERVALS = 2.8


@dataclass(frozen=True, slots=True)
class FusedFrame:
    """One fusion step's result.

    t_s: the instant fused (capture time on the server's clock, Unix seconds).
    fused_at_s: when fusion ran (server clock).
    raw: every sensor's bodies at ``t_s`` in the world frame (for viewers and debugging).
    extrapolated: ``(sensor_id, seconds)`` for each sensor late at its deadline and extrapolated
        that far to ``t_s`` (``alignment = "deadline"``; empty otherwise).
    """

    seq: int
    t_s: float
    fused_at_s: float
    persons: tuple[FusedPerson, ...]
    raw: tuple[View, ...]
    extrapolated: tuple[tuple[str, float], ...] = ()


class FusionHub:
    def __init__(self, settings: HubSettings, calibration: Calibration | None = None) -> None:
        self.settings = settings
        self._calibration = calibration
        self.sensors: dict[str, SensorState] = {}
        self._by_routing: dict[bytes, str] = {}
        self.rejected_unregistered: Counter[str] = Counter()
        self.pipeline = FusionPipeline(settings.fusion)
        self.latest: FusedFrame | None = None
        self.frame_arrived = asyncio.Event()
        self._seq = 0
        f = settings.fusion
        self.alignment = Alignment.of(f, settings.output_hz)
        """The output grid and when its next instant is fused (its ``due_s``: the deadline)."""
        self.started_s = time.time()
        self._requests: PendingRequests | None = None
        self._budget = RejectionBudget()
        self._probe: PeerProbe | None = None
        self._tap: MessageTap | None = None
        self.fusion_timing = RollingStats()
        """Seconds of compute per fusion step."""
        self.fusion_lag = RollingStats()
        """Server time when fusing minus the fused instant (the deliberate alignment wait)."""
        self.drift = DriftMonitor(settings.fusion) if settings.fusion.drift_detection else None
        """Has a sensor moved since its calibration? (None: ``drift_detection`` off.)"""

    # --- state set from outside --------------------------------------------------------------

    @property
    def calibration(self) -> Calibration | None:
        """The active stored calibration (None: none committed yet)."""
        return self._calibration

    def use_calibration(self, calibration: Calibration) -> None:
        """Fuse with ``calibration`` from the next step on (a commit, rollback or import)."""
        self._calibration = calibration
        for sensor in self.sensors.values():  # poses are read per step; lags are kept
            sensor.use_lag(calibrated_lag_s(calibration, sensor.sensor_id))
        if self.drift is not None:  # its windows hold points placed with the old poses
            self.drift.reset()

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
        one its id (fusion/registration.py); without it, recently heard counts as open."""
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
            if user_id is not None and message.sensor_id != user_id:
                self._refuse(None, "key_mismatch", routing_id, now_mono)
                return [
                    ErrorMessage(
                        "key_mismatch",
                        f"this agent's key belongs to sensor {user_id!r}, not "
                        f"{message.sensor_id!r}: run it with --id {user_id}",
                    )
                ]
            reply = self._register(
                message, routing_id, now_s, now_mono, authenticated=user_id is not None
            )
            if isinstance(reply, Welcome) and self._tap is not None:
                self._tap.on_hello(message.sensor_id, parts[0], now_s)
            return [reply]
        if sensor is None:
            return self._unregistered(routing_id, message, now_s, now_mono)
        sensor.last_heard_mono = now_mono
        sensor.connected = True
        match message:
            case Frame():
                if sensor.last_seq is not None and message.seq <= sensor.last_seq:
                    self._reject(sensor, "replayed_seq")
                    return []
                problem = sensor.admit(message, now_s)  # its seq is seen even if rejected
                if problem is not None:
                    self._reject(sensor, problem)
                    return []
                sensor.add_frame(message, now_s, now_mono)
                if self._tap is not None:
                    self._tap.on_frame(sensor.sensor_id, parts[0], now_s)
                self.frame_arrived.set()
            case Heartbeat(echo_ns=echo) if echo is not None:
                sensor.round_trip.add(echo / 1e9, message.t_ns / 1e9, now_s)
            case Heartbeat():
                pass
            case Bye():
                sensor.connected = False
                self._by_routing.pop(routing_id, None)
            case Response():
                if self._requests is None or not self._requests.resolve(sensor.sensor_id, message):
                    self._refuse(sensor, "unexpected_response", routing_id, now_mono)
            case _:
                self._refuse(sensor, "unexpected_type", routing_id, now_mono)
        return []

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
        """Count a protocol breach against the connection's budget (fusion/rejection_budget.py):
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
        sensor = new_sensor(hello, routing_id, now_mono)
        sensor.use_lag(calibrated_lag_s(self._calibration, hello.sensor_id))
        if existing is not None:
            # Keep the counters across reconnects: they describe the sensor, not the session.
            sensor.frames_received = existing.frames_received
            sensor.frames_rejected = existing.frames_rejected
            sensor.sequence_gaps = existing.sequence_gaps
            if existing.routing_id == routing_id:
                # The same connection (the same agent process, so the same clock) registering
                # again after a network pause keeps its clock estimates: starting over would map
                # its first frames with a one-way offset taken from whichever frame came first,
                # possibly a delayed one, and fuse old data as new.
                sensor.keep_clock_of(existing)
        self.sensors[hello.sensor_id] = sensor
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
        """Mark silent sensors offline; returns the sensors still online.

        Silent means nothing heard for ``OFFLINE_AFTER_INTERVALS`` heartbeat intervals (a little
        under the protocol's 3, so that with checks every 0.2 s a dead agent is offline within
        3 s).
        """
        liveness_s = self.settings.heartbeat_interval_s * OFFLINE_AFTER_INTERVALS
        online = []
        for sensor in self.sensors.values():
            # An agent busy answering our request (a depth capture) gets until the request's
            # own timeout before it counts as gone.
            limit = 10 * liveness_s if self._awaiting(sensor.sensor_id) else liveness_s
            if sensor.connected and now_mono - sensor.last_heard_mono > limit:
                logger.warning("sensor %s went silent; marked offline", sensor.sensor_id)
                sensor.connected = False  # its routing entry stays: see _unregistered
            if sensor.connected:
                online.append(sensor)
        return online

    # --- calibration ----------------------------------------------------------------------

    def pose_of(self, sensor_id: str) -> tuple[Matrix4 | None, str]:
        """``T_world_from_sensor`` (a moving sensor: its space's ``T_world_from_space``) and
        where it comes from: stored, sim_truth, manual, floor or uncalibrated (fusion/spaces.py)."""
        return resolve_pose(self._calibration, self.sensors, sensor_id)

    def connected_poses(self) -> dict[str, Matrix4]:
        """Every connected sensor's ``T_world_from_sensor`` (copies; those without one left out)."""
        poses = {s: self.pose_of(s)[0] for s, state in self.sensors.items() if state.connected}
        return {s: pose.copy() for s, pose in poses.items() if pose is not None}

    # --- fusion ---------------------------------------------------------------------------

    def fuse_step(self, now_s: float) -> FusedFrame | None:
        """Fuse the next instant of the output grid when the alignment policy says it is due
        (``FusionSettings.alignment``, :mod:`skelfuse.fusion.alignment`; None until then).

        Instants lie on a grid (``output_hz``, server clock), so the output rate is the sensors'
        rate however many sensors there are; each sensor contributes a sample interpolated (late
        at a deadline: extrapolated) to exactly that instant."""
        s = self.settings
        jittery = self.alignment.jittery
        instant = self.alignment.next_instant(
            live_timings(self.sensors.values(), now_s, s.max_wait_s), now_s
        )
        if self.alignment.jittery != jittery:  # judged once a second: each change noted
            logger.warning(self.alignment.jitter_report())
        if instant is None:
            return None
        t_target = instant.t_s
        started = time.perf_counter()
        pose_of = {sid: self.pose_of(sid)[0] for sid in self.sensors}.get  # once, not ~10 times
        with kernels.forced(kernels.mode()):  # asked ~20 times a step: read once (kernels.py)
            if instant.late or instant.left_out:
                views = views_with_late(
                    self.sensors.values(), pose_of, t_target, s.interpolation_gap_s,
                    dict(instant.late), instant.left_out, late_motions(self.pipeline, s.fusion),
                )  # fmt: skip
                persons = self.pipeline.update(views, t_target)
            else:
                persons, views = self.pipeline.step(
                    self.sensors.values(), pose_of, t_target, s.interpolation_gap_s
                )
        self._seq += 1
        fused = FusedFrame(self._seq, t_target, now_s, tuple(persons), tuple(views), instant.late)
        self.latest = fused
        if self.drift is not None:
            self.drift.observe(t_target, fused.persons)
        self.fusion_timing.add(time.perf_counter() - started)
        self.fusion_lag.add(now_s - t_target)
        return fused

    # --- views for the API ------------------------------------------------------------------

    def sensor_summary(self, now_mono: float) -> list[dict[str, object]]:
        """One row per known sensor, for ``GET /api/sensors`` (:func:`sensor_rows`)."""
        return sensor_rows(self.sensors.values(), self.pose_of, self.drift, now_mono)
