"""The hindsight oracle: per fused frame, the best correctly-labelled single view, against fusion.

Issue 10 asks fusion to beat *choosing*: per fused frame and true person, the oracle takes
every sensor's latest view of that person (the simulator's own frame: labels put right with its
truth, moved to the world by the sensor's true pose, scored against the truth at its own capture
instant, so without the interpolation and latency fusion pays), keeps those reporting at least
:data:`MIN_JOINTS` joints (a view whose legs are out of its field of view would otherwise win on
the trunk alone), and picks the one with the least MPJPE. No live system can do this: it knows
the truth. Target: fused MPJPE ≤ 0.9× the oracle's, overall and per joint group.

Run through ``python -m bench accuracy --oracle`` (with ``--quick``, ``--runs``); the methods
compared are :data:`ORACLE_METHODS` (the defaults; the same with each sensor's error kept at
its type's prior instead of learned).
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from bench.accuracy.metrics import Log
from bench.accuracy.runner import FPS, T0, SimulatedRig, _new_hub, feed
from bench.accuracy.scenarios import Scenario
from skelfuse.agent.sim.kinect_model import KinectV2Params, labels_put_right
from skelfuse.agent.sim.sensor_units import DEFAULT_ERROR_MODEL, ErrorModel
from skelfuse.fusion.rig_errors import GROUPS
from skelfuse.fusion.settings import LearningSettings
from skelfuse.protocol.transform import apply
from skelfuse.server.settings import FusionSettings

FloatArray = npt.NDArray[np.float64]
MIN_JOINTS: Final = 23
"""Joints (of 25) a view must report to be the oracle's choice."""
ORACLE = "hindsight oracle (best correct single view per frame)"
ORACLE_METHODS: Final[dict[str, FusionSettings]] = {
    "full (defaults)": FusionSettings(),
    "errors not learned (the sensor types' priors)": FusionSettings(
        learning=LearningSettings(enabled=False)
    ),
}


def group_mpjpe(errors: list[FloatArray]) -> dict[str, float]:
    """MPJPE (mm) overall and per joint group over (frame, person) rows of (25,) errors (m)."""
    if not errors:
        return {name: math.nan for name in ("all", *GROUPS)}
    stacked = np.stack(errors)
    out = {"all": float(np.nanmean(stacked) * 1000)}
    for name, joints in GROUPS.items():
        out[name] = float(np.nanmean(stacked[:, list(joints)]) * 1000)
    return out


def view_errors(
    joints_sensor: npt.NDArray[np.floating[Any]],
    mirrored: bool,
    pose: FloatArray,
    truth: FloatArray,
    true_joints: npt.NDArray[np.intp] | None = None,
) -> FloatArray:
    """(25,) per-joint error (m, NaN: not reported) of one view with its labels put right:
    by ``true_joints`` (the simulator's truth permutation, single-limb swaps included) when
    given, else by the whole-body ``mirrored`` flag."""
    joints = labels_put_right(np.asarray(joints_sensor, dtype=np.float64), mirrored, true_joints)
    return np.asarray(np.linalg.norm(apply(pose, joints) - truth, axis=1), dtype=np.float64)


def best_view(candidates: list[FloatArray]) -> FloatArray | None:
    """The candidate (25,) errors with the least mean among those reporting enough joints."""
    usable = [e for e in candidates if np.isfinite(e).sum() >= MIN_JOINTS]
    if not usable:
        return None
    return min(usable, key=lambda e: float(np.nanmean(e)))


def run_oracle(
    scenario: Scenario,
    seed: int,
    params: KinectV2Params,
    methods: dict[str, FusionSettings] = ORACLE_METHODS,
    error_model: ErrorModel = DEFAULT_ERROR_MODEL,
) -> dict[str, dict[str, float]]:
    """One simulated capture: MPJPE overall and per group (mm) per method and for the oracle.

    The oracle is sampled whenever the first method publishes a frame.
    """
    rig = SimulatedRig(scenario, seed, params, error_model)
    hubs = {label: _new_hub(fusion, rig.names, rig.poses) for label, fusion in methods.items()}
    first = next(iter(hubs))
    logs = {label: Log() for label in hubs}
    oracle: list[FloatArray] = []
    latest: dict[tuple[int, int], tuple[float, FloatArray]] = {}  # (sensor, person) → t, errors
    for capture in rig.captures():
        k = capture.sensor
        for o in capture.observations:
            truth = capture.truth[o.person]
            errors = view_errors(o.joints_m, o.mirrored, rig.poses[k], truth, o.true_joints)
            latest[(k, o.person)] = (capture.t_capture, errors)
        for label, hub in hubs.items():
            fused = feed(hub, capture)
            if fused is None:
                continue
            truth_at = rig.performer.joints_at(fused.t_s - T0)
            persons = [(p.person_id, p.joints) for p in fused.persons]
            logs[label].add(logs[label].frames + 1, persons, truth_at)
            if label != first:
                continue
            for person in range(truth_at.shape[0]):
                fresh = [
                    e for (_, who), (t, e) in latest.items()
                    if who == person and fused.t_s - t < 1.5 / FPS
                ]  # fmt: skip
                chosen = best_view(fresh)
                if chosen is not None:
                    oracle.append(chosen)
    out = {label: group_mpjpe(log.errors) for label, log in logs.items()}
    out[ORACLE] = group_mpjpe(oracle)
    return out


def print_oracle(results: dict[str, list[dict[str, dict[str, float]]]]) -> None:
    """The table: per scenario, median over seeds of MPJPE (mm) per group, and fused / oracle."""
    print("\n## Fused vs the hindsight oracle (MPJPE mm, median over seeds;")
    print("##   ratio = fused / oracle, target ≤ 0.90)\n")
    columns = ("all", *GROUPS)
    print("| scenario | method | " + " | ".join(columns) + " | ratio all / trunk / arms / legs |")
    print("|---|---|" + "---|" * (len(columns) + 1))
    for scenario, runs in results.items():
        labels = list(runs[0])
        med = {
            label: {c: float(np.median([r[label][c] for r in runs])) for c in columns}
            for label in labels
        }
        for label in labels:
            cells = " | ".join(f"{med[label][c]:.1f}" for c in columns)
            ratio = ""
            if label != ORACLE:
                ratio = " / ".join(f"{med[label][c] / med[ORACLE][c]:.2f}" for c in columns)
            print(f"| {scenario} | {label} | {cells} | {ratio} |")
