"""The fusion engine: the sensors' state, the output grid's alignment and the pipeline.

Socket-free and clock-free: it takes decoded messages (a sensor's ``hello``, its frames) and the
time as arguments (``now_s``: wall clock, Unix seconds; ``now_mono``: monotonic seconds), so the
same engine runs live, in recorded time and in simulated time. The server's sessions
(:class:`skelfuse.server.hub.FusionHub`) feed it what agents send; offline replay
(:mod:`skelfuse.recording.replay`) feeds it a recording's decoded messages.

Its health figures (the fusion lag here, the server's fusion time) are rolling statistics over
the last samples (:class:`RollingStats`, last section), without unbounded memory.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from statistics import median

from skelfuse.calibration.store import Calibration
from skelfuse.fusion.alignment import Alignment, live_timings
from skelfuse.fusion.drift import DriftMonitor
from skelfuse.fusion.extrapolation import late_motions, views_with_late
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.fusion.sensors import SensorState, calibrated_lag_s, new_sensor, sensor_rows
from skelfuse.fusion.settings import HubSettings
from skelfuse.fusion.spaces import resolve_pose
from skelfuse.fusion.views import FusedPerson, View
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Frame, Hello

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


class FusionEngine:
    """Sensors registered by their ``hello``, their frames, and the fusion step over them."""

    def __init__(self, settings: HubSettings, calibration: Calibration | None = None) -> None:
        self.settings = settings
        self._calibration = calibration
        self.sensors: dict[str, SensorState] = {}
        self.pipeline = FusionPipeline(settings.fusion)
        self.latest: FusedFrame | None = None
        self._seq = 0
        self.alignment = Alignment.of(settings.fusion, settings.output_hz)
        """The output grid and when its next instant is fused (its ``due_s``: the deadline)."""
        self.fusion_lag = RollingStats()
        """Server time when fusing minus the fused instant (the deliberate alignment wait)."""
        self.drift = DriftMonitor(settings.fusion) if settings.fusion.drift.enabled else None
        """Has a sensor moved since its calibration? (None: ``drift.enabled`` off.)"""

    # --- calibration ----------------------------------------------------------------------

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

    def pose_of(self, sensor_id: str) -> tuple[Matrix4 | None, str]:
        """``T_world_from_sensor`` (a moving sensor: its space's ``T_world_from_space``) and
        where it comes from: stored, sim_truth, manual, floor or uncalibrated (fusion/spaces.py)."""
        return resolve_pose(self._calibration, self.sensors, sensor_id)

    def connected_poses(self) -> dict[str, Matrix4]:
        """Every connected sensor's ``T_world_from_sensor`` (copies; those without one left out)."""
        poses = {s: self.pose_of(s)[0] for s, state in self.sensors.items() if state.connected}
        return {s: pose.copy() for s, pose in poses.items() if pose is not None}

    # --- sensors and their frames ---------------------------------------------------------

    def register(self, hello: Hello, routing_id: bytes, now_mono: float) -> SensorState:
        """Start the sensor of ``hello`` afresh on connection ``routing_id``, replacing any
        earlier state of that id (whether the id may be taken is the caller's judgement).

        The counters carry over (they describe the sensor, not the session), and so do the
        clock estimates when the connection is the same one: the same agent process, so the same
        clock, registering again after a network pause; starting over would map its first frames
        with a one-way offset taken from whichever frame came first, possibly a delayed one, and
        fuse old data as new.
        """
        existing = self.sensors.get(hello.sensor_id)
        sensor = new_sensor(hello, routing_id, now_mono)
        sensor.use_lag(calibrated_lag_s(self._calibration, hello.sensor_id))
        if existing is not None:
            sensor.frames_received = existing.frames_received
            sensor.frames_rejected = existing.frames_rejected
            sensor.sequence_gaps = existing.sequence_gaps
            if existing.routing_id == routing_id:
                sensor.keep_clock_of(existing)
        self.sensors[hello.sensor_id] = sensor
        return sensor

    def add_frame(
        self, sensor: SensorState, frame: Frame, now_s: float, now_mono: float
    ) -> str | None:
        """Buffer a registered sensor's ``frame``, received at ``now_s`` / ``now_mono``; or say
        why it is rejected (``replayed_seq``, or :meth:`SensorState.admit`'s reason), counted in
        the sensor's ``frames_rejected``."""
        if sensor.last_seq is not None and frame.seq <= sensor.last_seq:
            problem: str | None = "replayed_seq"
        else:
            problem = sensor.admit(frame, now_s)  # its seq is seen even if rejected
        if problem is not None:
            sensor.frames_rejected[problem] += 1
            return problem
        sensor.add_frame(frame, now_s, now_mono)
        return None

    def mark_silent_offline(
        self, now_mono: float, busy: Callable[[str], bool] | None = None
    ) -> list[SensorState]:
        """Mark silent sensors offline; returns the sensors still online.

        Silent means nothing heard for ``OFFLINE_AFTER_INTERVALS`` heartbeat intervals (a little
        under the protocol's 3, so that with checks every 0.2 s a dead agent is offline within
        3 s); a sensor ``busy`` says is answering a request (a depth capture) gets ten times
        that. An offline sensor must register again before its frames count.
        """
        liveness_s = self.settings.heartbeat_interval_s * OFFLINE_AFTER_INTERVALS
        online = []
        for sensor in self.sensors.values():
            limit = 10 * liveness_s if busy is not None and busy(sensor.sensor_id) else liveness_s
            if sensor.connected and now_mono - sensor.last_heard_mono > limit:
                logger.warning("sensor %s went silent; marked offline", sensor.sensor_id)
                sensor.connected = False
            if sensor.connected:
                online.append(sensor)
        return online

    # --- fusion ---------------------------------------------------------------------------

    def fuse_step(self, now_s: float) -> FusedFrame | None:
        """Fuse the next instant of the output grid when the alignment policy says it is due
        (``FusionSettings.alignment.policy``, :mod:`skelfuse.fusion.alignment`; None until then).

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
        pose_of = {sid: self.pose_of(sid)[0] for sid in self.sensors}.get  # once, not ~10 times
        if instant.late or instant.left_out:
            with self.pipeline.timer.stage("views"):  # 1–2 with the late sensors carried
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
        self.fusion_lag.add(now_s - t_target)
        return fused

    # --- views for the API ------------------------------------------------------------------

    def sensor_summary(self, now_mono: float) -> list[dict[str, object]]:
        """One row per known sensor, for ``GET /api/sensors`` (:func:`sensor_rows`)."""
        return sensor_rows(self.sensors.values(), self.pose_of, self.drift, now_mono)


def warm_up() -> None:
    """Compile every fusion stage's loops now (or load them from numba's cache); call at start,
    off any latency-bound loop, so no fused frame waits for a compilation. Each stage's own
    ``warm_up`` calls its loops once with the argument types the pipeline passes (a first start
    compiles for seconds, later starts load the cache)."""
    from skelfuse.fusion import (
        alignment,
        anatomy,
        bone_fit,
        bones,
        confidence,
        extrapolation,
        filters,
        identity,
        labels,
        limb_labels,
        mirror,
        rig_errors,
        view_factors,
        weigh,
        world_views,
    )

    stages = (
        anatomy, mirror, labels, limb_labels, confidence, view_factors, rig_errors,
        weigh, bone_fit, bones, identity, extrapolation, world_views,
        alignment, filters,
    )  # fmt: skip
    for stage in stages:
        stage.warm_up()


# --- Rolling statistics for health figures (fusion time, lag) without unbounded memory -----------


class RollingStats:
    """The last ``size`` samples of one quantity."""

    def __init__(self, size: int = 300) -> None:
        self._samples: deque[float] = deque(maxlen=size)

    def add(self, value: float) -> None:
        self._samples.append(value)

    @property
    def count(self) -> int:
        return len(self._samples)

    def median(self) -> float:
        return median(self._samples) if self._samples else 0.0

    def maximum(self) -> float:
        return max(self._samples, default=0.0)
