"""What a calibration run captures from the live hub: every sensor's bodies at common instants
while someone walks (:func:`capture_skeletons`), the reference's floor plane, and each sensor's
type (the solvers fit pairs with an ``rgb`` sensor with its own settings).

Time comes from the run's injected :class:`~skelfuse.server.clock.Clock`, so tests drive a whole
capture with a fake clock.
"""

from __future__ import annotations

from collections.abc import Sequence

from skelfuse.calibration.solvers import Samples, SensorTypes
from skelfuse.fusion.sensors import bodies_at
from skelfuse.protocol.wire import Body
from skelfuse.server.calibration_run_progress import RunProgress
from skelfuse.server.clock import Clock
from skelfuse.server.hub import FusionHub

SAMPLE_HZ = 30.0
SAMPLE_DELAY_S = 0.15
"""Sample a little in the past so every sensor's frames around the instant have arrived."""


async def capture_skeletons(
    hub: FusionHub,
    clock: Clock,
    sensors: Sequence[str],
    duration_s: float,
    tracker: RunProgress,
) -> Samples:
    """Every sensor's bodies at common instants (:data:`SAMPLE_HZ` per second) for
    ``duration_s`` seconds of ``clock``, the walk stage's progress by the clock."""
    samples: dict[str, list[tuple[Body, ...]]] = {s: [] for s in sensors}
    began = clock.monotonic()
    gap = hub.settings.interpolation_gap_s
    while (elapsed := clock.monotonic() - began) < duration_s:
        tracker.advance(elapsed / duration_s, f"{duration_s - elapsed:.0f} s left")
        t = clock.time() - SAMPLE_DELAY_S
        for sensor_id in sensors:
            sensor = hub.sensors.get(sensor_id)
            bodies = None
            if sensor is not None and sensor.connected:
                bodies = bodies_at(sensor.frames, t, gap, 1.5 / max(sensor.nominal_fps, 1))
            samples[sensor_id].append(bodies or ())
        await clock.sleep(1.0 / SAMPLE_HZ)
    return samples


def reference_floor_plane(
    hub: FusionHub, sensor_id: str
) -> tuple[float, float, float, float] | None:
    """The newest floor plane the sensor reported (Kinect ``FloorClipPlane``), if any."""
    sensor = hub.sensors.get(sensor_id)
    for timed in reversed(sensor.frames if sensor else ()):
        if timed.frame.floor is not None:
            return timed.frame.floor
    return None


def sensor_types(hub: FusionHub, sensors: Sequence[str]) -> SensorTypes:
    """Each of ``sensors``' ``sensor_type`` as it registered (those the hub does not know are
    left out: the solvers then use the depth sensors' settings)."""
    return {s: hub.sensors[s].sensor_type for s in sensors if s in hub.sensors}
