"""Prometheus metrics at ``/metrics``, read from the live state at scrape time.

Nothing is counted twice: the hub, the sensors and the broadcaster already keep their counters
for the REST API; this collector only exposes them, so the hot path pays nothing for metrics.
The BLAS thread gauge asks the loaded libraries themselves (threadpoolctl, about 2 ms a scrape),
so a process that did not pin them (:mod:`skelfuse.blas`) shows it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Mapping
from pathlib import Path

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector
from threadpoolctl import threadpool_info

from skelfuse.fusion.rig_errors import SensorErrors
from skelfuse.server.broadcast import Broadcaster
from skelfuse.server.hub import FusionHub


class SkelfuseCollector(Collector):
    def __init__(self, hub: FusionHub, broadcaster: Broadcaster) -> None:
        self.hub = hub
        self.broadcaster = broadcaster

    def collect(self) -> Iterator[Metric]:
        yield from _sensor_metrics(self.hub, time.monotonic())
        if self.hub.drift is not None:
            yield from _drift_metrics(self.hub)
        yield from _fusion_metrics(self.hub)
        yield from learned_error_metrics(self.hub.pipeline.errors.summary())
        yield from _feed_metrics(self.broadcaster)
        yield blas_threads()


def _sensor_metrics(hub: FusionHub, now: float) -> Iterator[Metric]:
    """Per sensor: frames accepted and rejected (by reason), sequence gaps, online, frame rate,
    last frame's age and clock offset; rejections from unregistered senders under ``""``.
    ``now`` is the server's monotonic clock, seconds."""
    frames = CounterMetricFamily(
        "skelfuse_sensor_frames", "Frames accepted from each sensor", labels=["sensor"]
    )
    rejected = CounterMetricFamily(
        "skelfuse_sensor_rejected", "Messages rejected, by sensor and reason",
        labels=["sensor", "reason"],
    )  # fmt: skip
    gaps = CounterMetricFamily(
        "skelfuse_sensor_sequence_gaps", "Frames an agent numbered but never delivered",
        labels=["sensor"],
    )  # fmt: skip
    connected = GaugeMetricFamily(
        "skelfuse_sensor_connected", "1 while the sensor is online", labels=["sensor"]
    )
    fps = GaugeMetricFamily(
        "skelfuse_sensor_fps", "Frames per second received (last 2 s)", labels=["sensor"]
    )
    age = GaugeMetricFamily(
        "skelfuse_sensor_last_frame_age_seconds", "Time since the last frame",
        labels=["sensor"],
    )  # fmt: skip
    offset = GaugeMetricFamily(
        "skelfuse_sensor_clock_offset_seconds",
        "Estimated server clock minus agent clock", labels=["sensor"],
    )  # fmt: skip
    for sensor in hub.sensors.values():
        sid = sensor.sensor_id
        frames.add_metric([sid], sensor.frames_received)
        gaps.add_metric([sid], sensor.sequence_gaps)
        for reason, count in sensor.frames_rejected.items():
            rejected.add_metric([sid, reason], count)
        connected.add_metric([sid], 1.0 if sensor.connected else 0.0)
        fps.add_metric([sid], sensor.fps(now) if sensor.connected else 0.0)
        if sensor.last_frame_mono is not None:
            age.add_metric([sid], now - sensor.last_frame_mono)
        if sensor.clock_offset_s is not None:
            offset.add_metric([sid], sensor.clock_offset_s)
    for reason, count in hub.rejected_unregistered.items():
        rejected.add_metric(["", reason], count)
    yield from (frames, rejected, gaps, connected, fps, age, offset)


def _fusion_metrics(hub: FusionHub) -> Iterator[Metric]:
    """Fused frames and people in the latest; once fusion has run, its compute time and lag."""
    fused = CounterMetricFamily("skelfuse_fused_frames", "Fused frames produced")
    fused.add_metric([], hub.latest.seq if hub.latest else 0)
    persons = GaugeMetricFamily("skelfuse_persons", "People in the latest fused frame")
    persons.add_metric([], len(hub.latest.persons) if hub.latest else 0)
    yield fused
    yield persons
    if hub.fusion_timing.count:
        compute = GaugeMetricFamily(
            "skelfuse_fusion_compute_seconds",
            "Fusion step compute time (median and max over the last 300 steps)",
            labels=["stat"],
        )
        compute.add_metric(["median"], hub.fusion_timing.median())
        compute.add_metric(["max"], hub.fusion_timing.maximum())
        yield compute
        lag = GaugeMetricFamily(
            "skelfuse_fusion_lag_seconds",
            "Server time at fusion minus the fused instant (median over the last 300)",
        )
        lag.add_metric([], hub.fusion_lag.median())
        yield lag


def learned_error_metrics(errors: Mapping[str, SensorErrors]) -> Iterator[Metric]:
    """Per sensor fusion has seen a person through: its learned RMS 3-D error (mm) per joint
    group (trunk, arms, legs; the prior's until ``learned``) and the evidence behind it
    (fusion/rig_errors.py; ``errors``: :meth:`RigErrors.summary`)."""
    error = GaugeMetricFamily(
        "skelfuse_sensor_learned_error_mm",
        "RMS 3-D error of the sensor's joints as fusion learned it from the rig, per joint "
        "group (the sensor type's prior until enough evidence)",
        labels=["sensor", "group"],
    )
    samples = GaugeMetricFamily(
        "skelfuse_sensor_learned_error_samples",
        "Evidence behind the learned error: forgotten views of a joint per joint",
        labels=["sensor"],
    )
    for sensor_id, learned in sorted(errors.items()):
        for group, mm in learned.groups_mm.items():
            error.add_metric([sensor_id, group], mm)
        samples.add_metric([sensor_id], learned.samples)
    yield from (error, samples)


def _feed_metrics(broadcaster: Broadcaster) -> Iterator[Metric]:
    """Per WebSocket client: frames sent and conflated; clients evicted and connected."""
    sent = CounterMetricFamily(
        "skelfuse_ws_client_sent", "Frames sent to each WebSocket client", labels=["client"]
    )
    conflated = CounterMetricFamily(
        "skelfuse_ws_client_conflated",
        "Frames a WebSocket client did not take before a newer one replaced them",
        labels=["client"],
    )
    for client in broadcaster.clients.values():
        label = str(client.client_id)
        sent.add_metric([label], client.sent)
        conflated.add_metric([label], client.conflated)
    evicted = CounterMetricFamily(
        "skelfuse_ws_clients_evicted", "WebSocket clients disconnected for stalling"
    )
    evicted.add_metric([], broadcaster.evicted)
    clients = GaugeMetricFamily("skelfuse_ws_clients", "Connected WebSocket clients")
    clients.add_metric([], len(broadcaster.clients))
    yield from (sent, conflated, evicted, clients)


def blas_threads() -> GaugeMetricFamily:
    """Threads each loaded BLAS library may use (1 once pinned); ``library`` is its file name,
    ``api`` the implementation (openblas, mkl, blis ...)."""
    gauge = GaugeMetricFamily(
        "skelfuse_blas_threads",
        "Threads each loaded BLAS library may use (1 when pinned; more can busy-wait a core)",
        labels=["library", "api"],
    )
    for info in threadpool_info():
        if info.get("user_api") == "blas":
            library = Path(str(info.get("filepath", ""))).name
            gauge.add_metric([library, str(info.get("internal_api", ""))], info["num_threads"])
    return gauge


def _drift_metrics(hub: FusionHub) -> Iterator[Metric]:
    """Per sensor: moved since its calibration (1/0), the latest correction estimated under the
    calibration, and its change since the pair's baseline (what the flag is decided on)."""
    assert hub.drift is not None
    moved = GaugeMetricFamily(
        "skelfuse_sensor_moved",
        "1 while the sensor looks moved since its calibration (drift detection)",
        labels=["sensor"],
    )
    rotation = GaugeMetricFamily(
        "skelfuse_sensor_drift_degrees",
        "Rotation the sensor's views need to agree with the others (latest estimate)",
        labels=["sensor"],
    )
    shift = GaugeMetricFamily(
        "skelfuse_sensor_drift_millimetres",
        "Shift of the person the sensor's views need to agree with the others (latest estimate)",
        labels=["sensor"],
    )
    change_rotation = GaugeMetricFamily(
        "skelfuse_sensor_drift_change_degrees",
        "Rotation of the sensor since its pair's baseline (what the moved flag is decided on)",
        labels=["sensor"],
    )
    change_shift = GaugeMetricFamily(
        "skelfuse_sensor_drift_change_millimetres",
        "Shift of the person since the sensor pair's baseline (what the moved flag is decided on)",
        labels=["sensor"],
    )
    for sensor_id, state in sorted(hub.drift.sensors.items()):
        moved.add_metric([sensor_id], 1.0 if state.moved else 0.0)
        if state.correction is not None:
            rotation.add_metric([sensor_id], state.correction.rotation_deg)
            shift.add_metric([sensor_id], state.correction.shift_mm)
        if state.relative is not None:
            change_rotation.add_metric([sensor_id], state.relative.rotation_deg)
            change_shift.add_metric([sensor_id], state.relative.shift_mm)
    yield from (moved, rotation, shift, change_rotation, change_shift)
