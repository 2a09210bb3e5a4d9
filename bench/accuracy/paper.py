"""Report A's own experiment: bone lengths pre-measured standing, then fused while walking."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from bench.accuracy.methods import BASE, BONE
from bench.accuracy.runner import FPS, T0, run_once, sensor_poses
from bench.accuracy.scenarios import Scenario
from skelfuse.agent.sim.kinect_model import KinectV2Params, SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.scenarios import Segment, Standing
from skelfuse.protocol.skeleton import BONES, JointId, TrackingState, bone_lengths
from skelfuse.protocol.transform import apply
from skelfuse.server.hub import FusionHub

FloatArray = npt.NDArray[np.float64]


def paper_experiment(seed: int = 0) -> dict[str, dict[str, float]]:
    """Two sensors; bone lengths pre-measured standing in front of sensor 1 for 3 s; then 50
    fused frames of walking: fused HipRight–KneeRight and KneeRight–AnkleRight lengths against
    the pre-measured ones, tracking-state weights vs tracking-state + bone-length weights."""
    params = KinectV2Params()
    poses = sensor_poses(2)
    front = poses[0][:3, 3]
    standing = Standing((0.0, 0.0), math.atan2(front[0], front[2]))
    kinect = SimulatedKinect(poses[0], params, seed=seed + 7)
    samples = []
    for n in range(int(3 * FPS)):
        obs = kinect.observe(standing.joints_at(0.0), T0 + n / FPS)
        for o in obs:
            tracked = o.states == TrackingState.TRACKED
            lengths = bone_lengths(apply(poses[0], o.joints_m))
            ok = np.array([tracked[p] and tracked[c] for p, c in BONES])
            samples.append(np.where(ok, lengths, np.nan))
    premeasured = np.nanmedian(np.stack(samples), axis=0)
    bones = {
        "HipRight–KneeRight": BONES.index((JointId.HIP_RIGHT, JointId.KNEE_RIGHT)),
        "KneeRight–AnkleRight": BONES.index((JointId.KNEE_RIGHT, JointId.ANKLE_RIGHT)),
    }
    truth_lengths = bone_lengths(standing.joints_at(0.0)[0])
    methods = {"tracking-state weights": BASE, "tracking-state + bone length": BONE}
    collected: dict[str, list[FloatArray]] = {label: [] for label in methods}

    def set_reference(label: str, hub: FusionHub) -> None:
        if label in methods and methods[label].weights.bone_length:
            hub.pipeline.set_default_bone_lengths(premeasured)

    scenario = Scenario("paper", Segment(ProceduralPerformer(1), 0.0, 6.3), 62 / FPS, 2, "")
    hubs: dict[str, FusionHub] = {}

    def keep(label: str, hub: FusionHub) -> None:
        set_reference(label, hub)
        hubs[label] = hub
        original = hub.fuse_step

        def wrapped(now_s: float) -> object:
            fused = original(now_s)
            if (
                label in collected
                and fused is not None
                and fused.persons
                and len(collected[label]) < 50
            ):
                collected[label].append(bone_lengths(fused.persons[0].joints))
            return fused

        hub.fuse_step = wrapped  # type: ignore[method-assign,assignment]

    run_once(scenario, seed, params, methods, on_hub=keep)
    out: dict[str, dict[str, float]] = {}
    for label, series in collected.items():
        lengths = np.stack(series)
        for bone, index in bones.items():
            diff = lengths[:, index] - premeasured[index]
            out[f"{label} | {bone}"] = {
                "frames": float(len(series)),
                "premeasured_mm": float(premeasured[index] * 1000),
                "true_mm": float(truth_lengths[index] * 1000),
                "mean_abs_diff_mm": float(np.nanmean(np.abs(diff)) * 1000),
                "sd_mm": float(np.nanstd(lengths[:, index]) * 1000),
            }
    return out
