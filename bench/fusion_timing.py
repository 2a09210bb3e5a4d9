"""In-process fusion cost per fused frame on the production classes, in simulated time."""

from __future__ import annotations

import math
import statistics
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from bench.fusion_stages import StageClock, stage_timers
from bench.load_agents import FPS, PERIOD_S, hello, sensor_layout
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.calibration.store import Calibration, SensorCalibration
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import apply, invert
from skelfuse.protocol.wire import Body, Frame, encode

Drive = Literal["arrivals", "period"]


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
    """Median ms per pipeline stage (bench/fusion_stages.py); the medians need not add up."""
    drive: Drive = "arrivals"
    """When ``fuse_step`` was called (:func:`fusion_timing`)."""
    late_per_frame: float = 0.0
    """Mean number of sensors carried forward (late at the deadline) per fused frame."""


def fusion_timing(
    sensors: int, bodies: int, steps: int = 1000, warmup: int = 100, drive: Drive = "arrivals"
) -> FusionTiming:
    """Median cost of one fused frame (and of ingesting one frame) on the production classes,
    and of each pipeline stage in it (bench/fusion_stages.py).

    Every third period is timed by stage, its wrappers around the stages for that period only;
    the step's own figures come from the other periods (``steps`` of them), which run the
    library untouched.

    ``drive``: when ``fuse_step`` is called. ``arrivals``, as the live loop does
    (server/ingest.py): after each frame arrives (0.5 ms after its capture), and at the pending
    instant's deadline when that comes first; only the calls that fused are timed. ``period``,
    as this bench did before 2026-11-23 16:00: once per frame period, a period after the
    instant, when every sensor's newest frame looks more than the deadline old, so under
    ``deadline`` every sensor is carried forward at every instant (the late path's worst case,
    not what the live server does)."""
    from skelfuse.fusion.engine import warm_up
    from skelfuse.protocol.feed import frame_json
    from skelfuse.server.broadcast import encode_message
    from skelfuse.server.hub import FusionHub
    from skelfuse.server.settings import Settings

    warm_up()  # as the server does at start: no step compiles
    poses = sensor_layout(sensors)
    settings = Settings()
    calibration = Calibration(1, 0.0, {s: SensorCalibration(p, "bench") for s, p in poses.items()})
    hub = FusionHub(settings, calibration)
    performer = ProceduralPerformer(bodies)
    states = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)
    t_start = math.floor(1_800_000_000.0 * FPS) / FPS
    ids = sorted(poses)
    for s in ids:
        hub.handle_message(s.encode(), [encode(hello(s))], t_start, 0.0)
    sensor_from_world = {s: invert(poses[s]) for s in ids}
    fuse: list[float] = []
    fuse_cpu: list[float] = []
    encode_times: list[float] = []
    handle: list[float] = []
    late_views = 0

    def step(now_s: float, measured: bool, by_stage: bool) -> bool:
        """One ``fuse_step`` at ``now_s``; its times kept when it fused and ``measured``: by
        stage (bench/fusion_stages.py) when ``by_stage``, else the step's own."""
        nonlocal late_views
        start, start_cpu = time.perf_counter(), time.thread_time()
        fused = hub.fuse_step(now_s)
        elapsed, elapsed_cpu = time.perf_counter() - start, time.thread_time() - start_cpu
        if fused is None or not measured:
            stages.discard()
            return fused is not None
        if by_stage:
            stages.finish(elapsed)
            return True
        start = time.perf_counter()
        encode_message(frame_json(fused, False, time.time()), binary=False)
        encode_times.append(time.perf_counter() - start)
        fuse.append(elapsed)
        fuse_cpu.append(elapsed_cpu)
        late_views += len(fused.extrapolated)
        return True

    # Sensors out of phase, as real ones are: 4 ms apart. Fused on arrival, time must not run
    # backwards, so the phases past a period wrap into it and the sensors arrive in phase order
    # (``period`` keeps the unwrapped phases it always had).
    phases = [0.002 + j * 0.004 for j in range(len(ids))]
    if drive == "arrivals":
        phases = [phase % PERIOD_S for phase in phases]
    order = sorted(enumerate(ids), key=lambda js: phases[js[0]])
    stages = StageClock()
    # One period in three timed by stage, the others as the library runs (the wrappers cost
    # ~3 % of a step: bench/fusion_stages.py). Three is prime to the bone model's refresh
    # period (10 steps), so both kinds of period see its refreshes as often.
    for k in range(warmup + 3 * steps):  # until ``steps`` untouched fused steps (1.5 × as many)
        if len(fuse) >= steps:
            break
        by_stage = k % 3 == 2
        with stage_timers(hub.pipeline, stages) if by_stage else nullcontext(stages):
            t = t_start + k * PERIOD_S
            world = performer.joints_at(k * PERIOD_S)
            measured = k >= warmup
            for j, s in order:
                phase = phases[j]
                arrival = t + phase + 0.0005
                bodies_ = tuple(
                    Body(b + 1, apply(sensor_from_world[s], world[b]).astype(np.float32), states)
                    for b in range(bodies)
                )
                payload = encode(Frame(k + 1, int((t + phase) * 1e9), bodies_))
                due = hub.alignment.due_s if drive == "arrivals" else None
                if due is not None and due <= arrival:  # the live loop's timer fires first
                    step(due, measured, by_stage)
                start = time.perf_counter()
                hub.handle_message(s.encode(), [payload], arrival, k * PERIOD_S)
                handle.append(time.perf_counter() - start)
                if drive == "arrivals":
                    step(arrival, measured, by_stage)
            if drive == "period" and not step(t + PERIOD_S, measured, by_stage):
                raise RuntimeError(f"fusion produced nothing at step {k}")
    if len(fuse) < steps:
        raise RuntimeError(f"{len(fuse)} of {steps} untouched steps fused in {3 * steps} periods")
    return FusionTiming(
        sensors,
        bodies,
        steps,
        statistics.median(fuse) * 1e3,
        float(np.percentile(fuse, 99)) * 1e3,
        statistics.median(fuse_cpu) * 1e3,
        statistics.median(stages.updates) * 1e3 if stages.updates else math.nan,
        statistics.median(encode_times) * 1e3,
        statistics.median(handle[warmup * sensors :]) * 1e3,
        stages.medians_ms(),
        drive,
        late_views / len(fuse),
    )
