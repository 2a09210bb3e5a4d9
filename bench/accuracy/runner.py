"""One simulated capture seen by every fusion method: the same sensor frames, as wire bytes, fed
to one production ``FusionHub`` per method in simulated time, scored against the truth."""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bench.accuracy.methods import BASE
from bench.accuracy.metrics import Log
from bench.accuracy.scenarios import Scenario
from skelfuse.agent.sim.kinect_model import KinectV2Params, Observation
from skelfuse.agent.sim.sensor_units import DEFAULT_ERROR_MODEL, ErrorModel
from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.sensors import TimedFrame
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.hub import FusionHub
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


@dataclass(frozen=True, slots=True)
class Capture:
    """One sensor frame of a simulated capture, as every hub receives it.

    truth: (persons, 25, 3) the performers at ``t_capture`` (world, metres); message: the frame
    as wire bytes; received: its arrival time (capture + network delay, the server's clock).
    """

    sensor: int
    name: str
    seq: int
    t_capture: float
    truth: FloatArray
    observations: list[Observation]
    message: bytes

    @property
    def received(self) -> float:
        return self.t_capture + NETWORK_DELAY_S


class SimulatedRig:
    """The performers and simulated sensors of one capture (one seed), and its frames in
    arrival order: what every benchmark feeds its hubs, so all compare the same frames.

    Each sensor starts at a random capture phase (plus the scenario's per-seed start delay).
    ``error_model`` picks the sensors' error model (default: every sensor a Kinect v2 with
    ``params``); random units are drawn from the run's seed (a stream of their own, so the
    phases, performers and sensor noise seeds stay those of the default).
    """

    def __init__(
        self,
        scenario: Scenario,
        seed: int,
        params: KinectV2Params,
        error_model: ErrorModel = DEFAULT_ERROR_MODEL,
    ) -> None:
        rng = np.random.default_rng(seed)
        self.performer, delays = scenario.performer, [0.0] * scenario.sensors
        if scenario.per_seed is not None:
            self.performer, delays = scenario.per_seed(np.random.default_rng(10_000 + seed))
        self.poses = sensor_poses(scenario.sensors)
        self.sensors = error_model.sensors(
            self.poses,
            [seed * 100 + k for k in range(len(self.poses))],
            seed,
            params,
        )
        self.names = [f"sim-{k + 1}" for k in range(len(self.sensors))]
        events: list[tuple[float, int]] = []
        for k in range(len(self.sensors)):
            phase = rng.uniform(0, 1 / FPS) + delays[k]
            count = int((scenario.duration_s - delays[k]) * FPS)
            events += [(T0 + phase + n / FPS, k) for n in range(count)]
        self._events = sorted(events)

    def captures(self) -> Iterator[Capture]:
        seqs = [0] * len(self.sensors)
        for t_capture, k in self._events:
            truth = self.performer.joints_at(t_capture - T0)
            observations = self.sensors[k].observe(truth, t_capture)
            seqs[k] += 1
            bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in observations)
            message = encode(Frame(seqs[k], int(t_capture * 1e9), bodies))
            yield Capture(k, self.names[k], seqs[k], t_capture, truth, observations, message)


def feed(hub: FusionHub, capture: Capture) -> FusedFrame | None:
    """Hand one frame to a hub as it arrives and run the fusion step, as the live loop does."""
    received = capture.received
    hub.handle_message(capture.name.encode(), [capture.message], received, received - T0)
    return hub.fuse_step(received)


def run_once(
    scenario: Scenario,
    seed: int,
    params: KinectV2Params,
    methods: dict[str, FusionSettings],
    on_hub: Callable[[str, FusionHub], None] | None = None,
    error_model: ErrorModel = DEFAULT_ERROR_MODEL,
) -> dict[str, dict[str, float]]:
    """One simulated capture seen by every method; returns the metrics per method."""
    rig = SimulatedRig(scenario, seed, params, error_model)
    names, poses = rig.names, rig.poses
    hubs: dict[str, tuple[FusionHub, set[int]]] = {}
    for label, fusion in methods.items():
        hubs[label] = (_new_hub(fusion, names, poses), set(range(len(names))))
    for k, name in enumerate(names):
        hubs[f"single {name}"] = (_new_hub(BASE, [name], [poses[k]]), {k})
    if on_hub is not None:
        for label, (hub, _) in hubs.items():
            on_hub(label, hub)
    logs = {label: Log() for label in hubs}
    frame_counters = dict.fromkeys(hubs, 0)
    swapped: dict[tuple[str, int], dict[int, bool]] = {}  # (sensor, seq) → tracking id → truth
    for capture in rig.captures():
        swapped[(capture.name, capture.seq)] = {
            o.tracking_id: o.mirrored for o in capture.observations
        }
        for label, (hub, members) in hubs.items():
            if capture.sensor not in members:
                continue
            fused = feed(hub, capture)
            if fused is None:
                continue
            frame_counters[label] += 1
            truth_at = rig.performer.joints_at(fused.t_s - T0)
            persons = [(p.person_id, p.joints) for p in fused.persons]
            logs[label].add(frame_counters[label], persons, truth_at,
                            label_decisions(hub, fused, swapped))  # fmt: skip
    return {label: log.summary() for label, log in logs.items()}


def label_decisions(
    hub: FusionHub, fused: FusedFrame, swapped: dict[tuple[str, int], dict[int, bool]]
) -> dict[int, list[tuple[bool, bool]]]:
    """Per fused person, each view's (swapped back by fusion, mirrored by the simulator).

    The truth is that of the frame fusion took the view's labels from: the nearer of the two
    frames around the fused instant (fusion.sensors.bodies_at). Fusion decides whole-body
    swaps only, so the truth is ``Observation.mirrored``; a single limb the tracker model fitted
    the wrong way round (``Observation.true_joints``) is no labelling decision of fusion's and
    shows in the joint errors instead.
    """
    out: dict[int, list[tuple[bool, bool]]] = {}
    for person in fused.persons:
        decisions = out.setdefault(person.person_id, [])
        for view in person.views:
            frame = _nearer_frame(list(hub.sensors[view.sensor_id].frames), fused.t_s)
            if frame is None:
                continue
            truth = swapped.get((view.sensor_id, frame.frame.seq), {}).get(view.tracking_id)
            if truth is not None:
                decisions.append((view.sensor_id in person.mirrored, truth))
    return out


def _nearer_frame(frames: list[TimedFrame], t_s: float) -> TimedFrame | None:
    """The frame whose bodies (and labels) ``bodies_at`` gives at ``t_s``."""
    if not frames:
        return None
    index = bisect_left([f.t_server_s for f in frames], t_s)
    if index == len(frames):
        return frames[-1]
    after = frames[index]
    if after.t_server_s == t_s or index == 0:
        return after
    before = frames[index - 1]
    gap = after.t_server_s - before.t_server_s
    alpha = (t_s - before.t_server_s) / gap if gap > 0 else 1.0
    return after if alpha >= 0.5 else before
