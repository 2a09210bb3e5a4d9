"""In-process fusion cost per fused frame on the production classes, in simulated time."""

from __future__ import annotations

import math
import statistics
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final, Literal

import numpy as np
import numpy.typing as npt

from bench.live.agents import FPS, PERIOD_S, hello, sensor_layout
from bench.live.fusion_stages import StageClock, stage_timers
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.calibration.store import Calibration, SensorCalibration
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, invert
from skelfuse.protocol.wire import Body, Frame, encode

if TYPE_CHECKING:
    from skelfuse.server.hub import FusionHub

Drive = Literal["arrivals", "period"]
FloatArray = npt.NDArray[np.float64]


@dataclass
class FusionTiming:
    """Medians (ms) per fused frame for ``sensors`` × ``bodies`` over ``steps`` steps.

    ``fuse_step*`` and ``encode_json_ms`` come from the ``steps`` periods run as the library
    runs; ``tracker_ms`` (``FusionPipeline.update``) and ``stages_ms`` from the periods timed by
    stage in between them (half as many: :func:`fusion_timing`)."""

    sensors: int
    bodies: int
    steps: int
    fuse_step_ms: float
    fuse_step_p99_ms: float
    fuse_step_cpu_ms: float
    tracker_ms: float
    encode_json_ms: float
    handle_message_ms: float
    stages_ms: dict[str, float] = field(default_factory=dict)
    """Median ms per pipeline stage (bench/live/fusion_stages.py); the medians need not add up."""
    drive: Drive = "arrivals"
    """When ``fuse_step`` was called (:func:`fusion_timing`)."""
    late_per_frame: float = 0.0
    """Mean number of sensors carried forward (late at the deadline) per fused frame."""


def fusion_timing(
    sensors: int, bodies: int, steps: int = 1000, warmup: int = 100, drive: Drive = "arrivals"
) -> FusionTiming:
    """Median cost of one fused frame (and of ingesting one frame) on the production classes,
    and of each pipeline stage in it (bench/live/fusion_stages.py).

    Every third period is timed by stage, its wrappers around the stages for that period only;
    the step's own figures come from the other periods (``steps`` of them), which run the
    library untouched.

    ``drive``: when ``fuse_step`` is called. ``arrivals``, as the live loop does
    (server/ingest.py): after each frame arrives (0.5 ms after its capture), and at the pending
    instant's deadline when that comes first; only the calls that fused are timed. ``period``,
    as this bench did at first: once per frame period, a period after the instant, when every
    sensor's newest frame looks more than the deadline old, so under ``deadline`` every sensor
    is carried forward at every instant (the late path's worst case, not what the live server
    does)."""
    from skelfuse.fusion.engine import warm_up

    warm_up()  # as the server does at start: no step compiles
    poses = sensor_layout(sensors)
    t_start = math.floor(1_800_000_000.0 * FPS) / FPS
    times = _StepTimes(_hub_with_sensors(poses, t_start), StageClock())
    hub = times.hub
    performer = ProceduralPerformer(bodies)
    ids = sorted(poses)
    sensor_from_world = {s: invert(poses[s]) for s in ids}
    handle: list[float] = []
    # Sensors out of phase, as real ones are: 4 ms apart. Fused on arrival, time must not run
    # backwards, so the phases past a period wrap into it and the sensors arrive in phase order
    # (``period`` keeps the unwrapped phases it always had).
    phases = [0.002 + j * 0.004 for j in range(len(ids))]
    if drive == "arrivals":
        phases = [phase % PERIOD_S for phase in phases]
    order = sorted(enumerate(ids), key=lambda js: phases[js[0]])
    # One period in three timed by stage, the others as the library runs (the wrappers cost
    # ~3 % of a step: bench/live/fusion_stages.py). Three is prime to the bone model's refresh
    # period (10 steps), so both kinds of period see its refreshes as often.
    for k in range(warmup + 3 * steps):  # until ``steps`` untouched fused steps (1.5 × as many)
        if len(times.fuse) >= steps:
            break
        by_stage = k % 3 == 2
        with stage_timers(hub.pipeline, times.stages) if by_stage else nullcontext(times.stages):
            t = t_start + k * PERIOD_S
            world = performer.joints_at(k * PERIOD_S)
            measured = k >= warmup
            for j, s in order:
                phase = phases[j]
                arrival = t + phase + 0.0005
                payload = _frame(k + 1, t + phase, sensor_from_world[s], world)
                due = hub.alignment.due_s if drive == "arrivals" else None
                if due is not None and due <= arrival:  # the live loop's timer fires first
                    times.step(due, measured, by_stage)
                start = time.perf_counter()
                hub.handle_message(s.encode(), [payload], arrival, k * PERIOD_S)
                handle.append(time.perf_counter() - start)
                if drive == "arrivals":
                    times.step(arrival, measured, by_stage)
            if drive == "period" and not times.step(t + PERIOD_S, measured, by_stage):
                raise RuntimeError(f"fusion produced nothing at step {k}")
    if len(times.fuse) < steps:
        raise RuntimeError(
            f"{len(times.fuse)} of {steps} untouched steps fused in {3 * steps} periods"
        )
    handle_ms = statistics.median(handle[warmup * sensors :]) * 1e3
    return times.timing(sensors, bodies, steps, handle_ms, drive)


def _hub_with_sensors(poses: dict[str, Matrix4], t_start: float) -> FusionHub:
    """A hub with default settings, calibrated at ``poses``, each sensor said hello at
    ``t_start`` (s)."""
    from skelfuse.server.hub import FusionHub
    from skelfuse.server.settings import Settings

    calibration = Calibration(1, 0.0, {s: SensorCalibration(p, "bench") for s, p in poses.items()})
    hub = FusionHub(Settings(), calibration)
    for s in sorted(poses):
        hub.handle_message(s.encode(), [encode(hello(s))], t_start, 0.0)
    return hub


_TRACKED: Final = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)


def _frame(number: int, capture_s: float, sensor_from_world: Matrix4, world: FloatArray) -> bytes:
    """The agent's frame ``number`` captured at ``capture_s`` (s): the (B, 25, 3) ``world``
    bodies seen in its frame, every joint tracked."""
    bodies = tuple(
        Body(b + 1, apply(sensor_from_world, world[b]).astype(np.float32), _TRACKED)
        for b in range(len(world))
    )
    return encode(Frame(number, int(capture_s * 1e9), bodies))


@dataclass
class _StepTimes:
    """The fused steps' times (s), as :func:`fusion_timing` takes them."""

    hub: FusionHub
    stages: StageClock
    fuse: list[float] = field(default_factory=list)
    fuse_cpu: list[float] = field(default_factory=list)
    encode: list[float] = field(default_factory=list)
    late_views: int = 0

    def step(self, now_s: float, measured: bool, by_stage: bool) -> bool:
        """One ``fuse_step`` at ``now_s``; its times kept when it fused and ``measured``: by
        stage (bench/live/fusion_stages.py) when ``by_stage``, else the step's own."""
        from skelfuse.protocol.feed import frame_json
        from skelfuse.server.broadcast import encode_message

        start, start_cpu = time.perf_counter(), time.thread_time()
        fused = self.hub.fuse_step(now_s)
        elapsed, elapsed_cpu = time.perf_counter() - start, time.thread_time() - start_cpu
        if fused is None or not measured:
            self.stages.discard()
            return fused is not None
        if by_stage:
            self.stages.finish(elapsed)
            return True
        start = time.perf_counter()
        encode_message(frame_json(fused, False, time.time()), binary=False)
        self.encode.append(time.perf_counter() - start)
        self.fuse.append(elapsed)
        self.fuse_cpu.append(elapsed_cpu)
        self.late_views += len(fused.extrapolated)
        return True

    def timing(
        self, sensors: int, bodies: int, steps: int, handle_ms: float, drive: Drive
    ) -> FusionTiming:
        """The medians of what was timed; ``handle_ms`` the ingest's."""
        stages = self.stages
        return FusionTiming(
            sensors,
            bodies,
            steps,
            statistics.median(self.fuse) * 1e3,
            float(np.percentile(self.fuse, 99)) * 1e3,
            statistics.median(self.fuse_cpu) * 1e3,
            statistics.median(stages.updates) * 1e3 if stages.updates else math.nan,
            statistics.median(self.encode) * 1e3,
            handle_ms,
            stages.medians_ms(),
            drive,
            self.late_views / len(self.fuse),
        )
