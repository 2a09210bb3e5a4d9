"""One simulated capture seen by every fusion method: the same sensor frames, as wire bytes, fed
to one production ``FusionHub`` per method in simulated time, scored against the truth."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from bench.accuracy_methods import BASE
from bench.accuracy_metrics import Log
from bench.accuracy_scenarios import Scenario
from skelfuse.agent.sim.kinect_model import KinectV2Params, SimulatedKinect
from skelfuse.fusion.hub import FusionHub
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.settings import FusionSettings, Settings

FPS = 30.0
NETWORK_DELAY_S = 0.002
T0 = 1_800_000_000.0
FloatArray = npt.NDArray[np.float64]


def sensor_poses(count: int, radius: float = 3.0, height: float = 1.0) -> list[FloatArray]:
    """Sensors on a circle looking at the middle: 2 are 90° apart (a corner rig), 3 at 120°,
    4 at 90° all round."""
    spacing = math.pi / 2 if count == 2 else 2 * math.pi / count
    poses = []
    for i in range(count):
        angle = spacing * i + math.radians(15.0)
        position = (radius * math.sin(angle), height, radius * math.cos(angle))
        poses.append(look_at_pose(position, (0.0, 0.9, 0.0)))
    return poses


def _new_hub(fusion: FusionSettings, names: list[str], poses: list[FloatArray]) -> FusionHub:
    """A production hub with ``fusion`` settings, the named sensors registered at true poses."""
    hub = FusionHub(Settings(fusion=fusion))
    for name, pose in zip(names, poses, strict=True):
        hello = Hello(name, "sim", "bench", FPS, 0, pose_hint=pose, pose_hint_source="sim_truth")
        hub.handle_message(name.encode(), [encode(hello)], T0, 0.0)
    return hub


def run_once(
    scenario: Scenario,
    seed: int,
    params: KinectV2Params,
    methods: dict[str, FusionSettings],
    on_hub: Callable[[str, FusionHub], None] | None = None,
) -> dict[str, dict[str, float]]:
    """One simulated capture seen by every method; returns the metrics per method."""
    rng = np.random.default_rng(seed)
    poses = sensor_poses(scenario.sensors)
    kinects = [SimulatedKinect(p, params, seed=seed * 100 + k) for k, p in enumerate(poses)]
    names = [f"sim-{k + 1}" for k in range(len(kinects))]
    hubs: dict[str, tuple[FusionHub, set[int]]] = {}
    for label, fusion in methods.items():
        hubs[label] = (_new_hub(fusion, names, poses), set(range(len(names))))
    for k, name in enumerate(names):
        hubs[f"single {name}"] = (_new_hub(BASE, [name], [poses[k]]), {k})
    if on_hub is not None:
        for label, (hub, _) in hubs.items():
            on_hub(label, hub)
    events: list[tuple[float, int]] = []
    for k in range(len(kinects)):
        phase = rng.uniform(0, 1 / FPS)
        events += [(T0 + phase + n / FPS, k) for n in range(int(scenario.duration_s * FPS))]
    events.sort()
    logs = {label: Log() for label in hubs}
    frame_counters = dict.fromkeys(hubs, 0)
    seqs = [0] * len(kinects)
    for t_capture, k in events:
        truth = scenario.performer.joints_at(t_capture - T0)
        observations = kinects[k].observe(truth, t_capture)
        seqs[k] += 1
        bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in observations)
        message = encode(Frame(seqs[k], int(t_capture * 1e9), bodies))
        received = t_capture + NETWORK_DELAY_S
        for label, (hub, members) in hubs.items():
            if k not in members:
                continue
            hub.handle_message(names[k].encode(), [message], received, received - T0)
            fused = hub.fuse_step(received)
            if fused is None:
                continue
            frame_counters[label] += 1
            truth_at = scenario.performer.joints_at(fused.t_s - T0)
            persons = [(p.person_id, p.joints) for p in fused.persons]
            logs[label].add(frame_counters[label], persons, truth_at)
    return {label: log.summary() for label, log in logs.items()}
