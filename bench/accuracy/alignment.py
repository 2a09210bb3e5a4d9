"""The alignment policies side by side (issue 11 item 1; ``python -m bench accuracy --alignment``).

Every scenario's captures go, as wire bytes in simulated time, to one production
:class:`server.hub.FusionHub` per policy (the default fusion settings otherwise), exactly as
``runner`` feeds them, plus the live fusion loop's timer: before each arrival, every
deadline (``hub.alignment.due_s``) that has passed gets its fusion step at that moment.

Per policy: MPJPE (mm, as the accuracy table), its difference from ``aligned`` on the same
frames, the alignment wait (server time of the fusion step minus the fused instant: what the
policy adds to the latency; as ``skelfuse_fusion_lag_seconds``; the sensors' clocks are mapped
one way here, so the delivery delay itself is not in it), mean and p99, and the share of fused
frames with a sensor extrapolated. ``jitter_ms``: each frame's delivery is delayed by a further
exponential amount of that mean (in order per sensor, as over one TCP connection), so that
deadlines meet late frames as on a real network; 0 is the accuracy benchmark's fixed 2 ms.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from bench.accuracy.metrics import Log
from bench.accuracy.runner import (
    NETWORK_DELAY_S,
    T0,
    Capture,
    SimulatedRig,
    _new_hub,
    label_decisions,
)
from bench.accuracy.scenarios import Scenario
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.sensor_units import DEFAULT_ERROR_MODEL, ErrorModel
from skelfuse.fusion.engine import FusedFrame
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import FusionSettings

DEFAULT = FusionSettings()
OWN = replace(DEFAULT, alignment=replace(DEFAULT.alignment, policy="deadline", predictor="own"))
TRACK = replace(DEFAULT, alignment=replace(DEFAULT.alignment, policy="deadline", predictor="track"))
HORIZON = replace(
    TRACK, alignment=replace(TRACK.alignment, grid="horizon", skip_expected_late=True)
)
VIEWS = replace(HORIZON, alignment=replace(HORIZON.alignment, predictor="views"))
ALL_POLICIES: dict[str, FusionSettings] = {
    "aligned": replace(DEFAULT, alignment=replace(DEFAULT.alignment, policy="aligned")),
    "phased": replace(DEFAULT, alignment=replace(DEFAULT.alignment, policy="phased")),
    # The first version: late sensors linear from their own two newest frames.
    "own 5 ms": replace(OWN, alignment=replace(OWN.alignment, deadline_s=0.005)),
    "own 10 ms": replace(OWN, alignment=replace(OWN.alignment, deadline_s=0.010)),
    "own 20 ms": replace(OWN, alignment=replace(OWN.alignment, deadline_s=0.020)),
    # Late sensors carried by their person's filtered motion (velocity and acceleration).
    "track 5 ms": replace(TRACK, alignment=replace(TRACK.alignment, deadline_s=0.005)),
    "track 10 ms": replace(TRACK, alignment=replace(TRACK.alignment, deadline_s=0.010)),
    "track 20 ms": replace(TRACK, alignment=replace(TRACK.alignment, deadline_s=0.020)),
    "track v 10 ms": replace(TRACK, alignment=replace(TRACK.alignment, predict_acceleration=False)),
    # ... with the grid put for the shortest extrapolation, expected-late sensors not waited for.
    "horizon 5 ms": replace(HORIZON, alignment=replace(HORIZON.alignment, deadline_s=0.005)),
    "horizon 10 ms": replace(HORIZON, alignment=replace(HORIZON.alignment, deadline_s=0.010)),
    "horizon 15 ms": replace(HORIZON, alignment=replace(HORIZON.alignment, deadline_s=0.015)),
    "horizon 20 ms": replace(HORIZON, alignment=replace(HORIZON.alignment, deadline_s=0.020)),
    "horizon no skip 10 ms": replace(
        HORIZON, alignment=replace(HORIZON.alignment, skip_expected_late=False)
    ),
    "horizon own 10 ms": replace(HORIZON, alignment=replace(HORIZON.alignment, predictor="own")),
    "horizon own 15 ms": replace(
        HORIZON, alignment=replace(HORIZON.alignment, predictor="own", deadline_s=0.015)
    ),
    "horizon own 20 ms": replace(
        HORIZON, alignment=replace(HORIZON.alignment, predictor="own", deadline_s=0.020)
    ),
    # ... late sensors carried by what their person's on-time views saw meanwhile (horizon grid).
    "views 2 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.002)),
    "views 3 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.003)),
    "views 5 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.005)),
    "views 6 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.006)),
    "views 7 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.007)),
    "views 8 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.008)),
    "views 10 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.010)),
    "views 12 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.012)),
    "views 15 ms": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_s=0.015)),
    "views no skip 10 ms": replace(
        VIEWS, alignment=replace(VIEWS.alignment, skip_expected_late=False)
    ),
    # ... without the fall-back to ``phased``'s wait on a jittery link (before 2026-11-24).
    "views 7 ms no fallback": replace(
        VIEWS, alignment=replace(VIEWS.alignment, jitter_fallback_s=0.0)
    ),
    "views 7 ms fallback 3 ms": replace(
        VIEWS, alignment=replace(VIEWS.alignment, jitter_fallback_s=0.003)
    ),
    # ... without the grace for a sensor expected on time that missed the deadline (before
    # 2026-11-24 20:30), and with a longer one.
    "views 7 ms no grace": replace(VIEWS, alignment=replace(VIEWS.alignment, deadline_grace_s=0.0)),
    "views 7 ms grace 10 ms": replace(
        VIEWS, alignment=replace(VIEWS.alignment, deadline_grace_s=0.010)
    ),
}
"""Every policy the bench knows (the extrapolation bound is the default's, 34 ms, for every
one); ``--policies`` picks some (``aligned`` always runs: the differences are against it)."""
POLICIES: dict[str, FusionSettings] = {
    label: ALL_POLICIES[label]
    for label in ("aligned", "phased", "own 10 ms", "track 10 ms", "horizon 10 ms", "views 7 ms")
}
"""The policies compared by default (``views 7 ms`` is the server's default setting)."""
Figures = dict[str, float]


def chosen_policies(labels: str | None) -> dict[str, FusionSettings]:
    """``--policies``: comma-separated labels of :data:`ALL_POLICIES` (None: :data:`POLICIES`),
    ``aligned`` first whether named or not.

    Raises:
        ValueError: a label that is not a known policy.
    """
    if labels is None:
        return dict(POLICIES)
    wanted = [label.strip() for label in labels.split(",") if label.strip()]
    unknown = [label for label in wanted if label not in ALL_POLICIES]
    if unknown:
        raise ValueError(f"unknown policies {unknown}; known: {', '.join(ALL_POLICIES)}")
    return {label: ALL_POLICIES[label] for label in ["aligned", *wanted]}


def deliver(hub: FusionHub, capture: Capture, arrival_s: float) -> list[FusedFrame]:
    """The deadlines due before ``arrival_s`` (the live loop's timer), then the frame's arrival
    and its fusion step (the live loop's wake on a frame); the frames fused, in order."""
    fused: list[FusedFrame] = []
    while (due := hub.alignment.due_s) is not None and due <= arrival_s:
        if (frame := hub.fuse_step(due)) is not None:
            fused.append(frame)
    hub.handle_message(capture.name.encode(), [capture.message], arrival_s, arrival_s - T0)
    if (frame := hub.fuse_step(arrival_s)) is not None:
        fused.append(frame)
    return fused


def arrivals(captures: list[Capture], jitter_ms: float, seed: int) -> list[tuple[float, Capture]]:
    """Each capture's arrival (server clock), in arrival order: the fixed network delay plus an
    exponential jitter of mean ``jitter_ms``, never before the same sensor's previous frame."""
    rng = np.random.default_rng(20_000 + seed)
    last: dict[str, float] = {}
    out = []
    for capture in captures:
        extra = rng.exponential(jitter_ms / 1000) if jitter_ms > 0 else 0.0
        arrival = max(capture.t_capture + NETWORK_DELAY_S + extra, last.get(capture.name, 0.0))
        last[capture.name] = arrival
        out.append((arrival, capture))
    out.sort(key=lambda item: item[0])
    return out


def run_alignment(
    scenario: Scenario,
    seed: int,
    params: KinectV2Params,
    jitter_ms: float = 0.0,
    policies: dict[str, FusionSettings] | None = None,
    error_model: ErrorModel = DEFAULT_ERROR_MODEL,
) -> dict[str, Figures]:
    """One simulated capture fused under every policy; figures per policy (module docstring)."""
    policies = POLICIES if policies is None else policies
    rig = SimulatedRig(scenario, seed, params, error_model)
    hubs = {label: _new_hub(s, rig.names, rig.poses) for label, s in policies.items()}
    logs = {label: Log() for label in hubs}
    waits: dict[str, list[float]] = {label: [] for label in hubs}
    extrapolated = dict.fromkeys(hubs, 0)
    swapped: dict[tuple[str, int], dict[int, bool]] = {}  # (sensor, seq) → tracking id → truth
    for arrival, capture in arrivals(list(rig.captures()), jitter_ms, seed):
        swapped[(capture.name, capture.seq)] = {
            o.tracking_id: o.mirrored for o in capture.observations
        }
        for label, hub in hubs.items():
            for fused in deliver(hub, capture, arrival):
                waits[label].append(fused.fused_at_s - fused.t_s)
                extrapolated[label] += bool(fused.extrapolated)
                truth = rig.performer.joints_at(fused.t_s - T0)
                persons = [(p.person_id, p.joints) for p in fused.persons]
                labels = label_decisions(hub, fused, swapped)
                logs[label].add(logs[label].frames + 1, persons, truth, labels)
    out: dict[str, Figures] = {}
    for label, log in logs.items():
        wait_ms = np.array(waits[label]) * 1000
        summary = log.summary()
        out[label] = {
            "mpjpe_mm": summary["mpjpe_mm"],
            "jitter_mm": summary["jitter_mm"],
            "wrong_labels": summary["wrong_labels"],
            "wait_mean_ms": float(wait_ms.mean()) if wait_ms.size else math.nan,
            "wait_p99_ms": float(np.percentile(wait_ms, 99)) if wait_ms.size else math.nan,
            "extrapolated": extrapolated[label] / max(len(wait_ms), 1),
            "frames": float(len(wait_ms)),
        }
    return out


def print_alignment(
    results: dict[str, list[dict[str, Figures]]], groups: dict[str, list[str]], jitter_ms: float
) -> dict[str, dict[str, Figures]]:
    """Per scenario group and policy: MPJPE (mean over runs), its difference from ``aligned``
    (mean of the per-run differences, and the worst run), the wait's mean and p99 (mean over
    runs), frames with a sensor extrapolated; returns the rows."""
    print(f"\nAlignment policies (delivery 2 ms + exponential jitter of mean {jitter_ms:g} ms)\n")
    print("| scenario | policy | MPJPE mm | Δ vs aligned mm (worst run) | jitter mm "
          "| wrong labels % | wait mean ms | wait p99 ms | frames extrapolated "
          "| fused frames |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    summary: dict[str, dict[str, Figures]] = {}
    for group, names in groups.items():
        runs = [run for name in names for run in results[name]]
        rows: dict[str, Figures] = {}
        for label in runs[0]:
            deltas = [run[label]["mpjpe_mm"] - run["aligned"]["mpjpe_mm"] for run in runs]
            row = {key: float(np.mean([run[label][key] for run in runs])) for key in runs[0][label]}
            row["delta_mm"], row["worst_delta_mm"] = float(np.mean(deltas)), float(max(deltas))
            rows[label] = row
            print(
                f"| {group} | {label} | {row['mpjpe_mm']:.1f} | {row['delta_mm']:+.2f} "
                f"({row['worst_delta_mm']:+.2f}) | {row['jitter_mm']:.2f} | "
                f"{row['wrong_labels']:.2%} | {row['wait_mean_ms']:.1f} | "
                f"{row['wait_p99_ms']:.1f} | {row['extrapolated']:.0%} | {row['frames']:.0f} |"
            )
        summary[group] = rows
    return summary
