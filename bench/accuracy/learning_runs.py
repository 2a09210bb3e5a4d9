"""The runs of the learned-errors benchmark (:mod:`bench.accuracy.learning`): one take seen by
fusion with errors learned and with the priors, the plain mean and each sensor alone, scored
against the truth and the hindsight oracle; the learned errors against each view's true error;
and a take in which one sensor is moved while fusion keeps its old calibration.

Errors are metres in the world frame as measured, reported in mm. The true error of a view is
the simulator's own: labels put right by its truth (``Observation.true_joints``), moved to the
world by the sensor's *true* pose (after a move, the new one), against the truth at the
capture instant.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.stats import rankdata

from bench.accuracy.methods import BASE, METHODS
from bench.accuracy.metrics import Log
from bench.accuracy.oracle import best_view, group_mpjpe, view_errors
from bench.accuracy.runner import FPS, T0, Capture, SimulatedRig, _new_hub, feed, label_decisions
from bench.accuracy.scenarios import Scenario
from skelfuse.agent.sim.kinect_model import KinectV2Params, Observation
from skelfuse.agent.sim.sensor_units import ErrorModel, SensorParams, SimulatedSensor
from skelfuse.fusion.rig_errors import GROUPS
from skelfuse.fusion.settings import LearningSettings
from skelfuse.protocol.transform import apply, axis_rotation, invert
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import FusionSettings

FloatArray = npt.NDArray[np.float64]
LEARNED = "learned"
PRIORS = "priors"
PLAIN = "plain mean"
ORACLE = "oracle"
FUSION: dict[str, FusionSettings] = {
    LEARNED: FusionSettings(),
    PRIORS: FusionSettings(learning=LearningSettings(enabled=False)),
    PLAIN: METHODS["plain mean"],
}
"""The fused methods of a take: the defaults, the same with the sensor types' priors kept, and
the plain tracking-state mean."""
TRUTH_WINDOW_S = 30.0
"""The learned errors are compared with the views' true errors over this last stretch."""
SAMPLE_EVERY_S = 0.5
"""How often the moved sensor's learned error is read in a move take."""


def spearman(a: Sequence[float], b: Sequence[float]) -> float:
    """Spearman's rank correlation of paired values (ties ranked by their mean rank), pairs
    with a NaN left out; NaN with fewer than 3 pairs or a constant side."""
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    keep = np.isfinite(x) & np.isfinite(y)
    if keep.sum() < 3:
        return math.nan
    rx, ry = rankdata(x[keep]), rankdata(y[keep])
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return math.nan
    return float(np.corrcoef(rx, ry)[0, 1])


@dataclass(frozen=True, slots=True)
class SensorMove:
    """Sensor ``sensor`` (index) turns ``yaw_deg`` about the vertical through it and shifts
    ``shift_mm`` along its own +X made level, ``at_s`` seconds into the take."""

    sensor: int
    yaw_deg: float
    shift_mm: float
    at_s: float

    def pose_after(self, pose: FloatArray) -> FloatArray:
        """(4, 4) ``T_world_from_sensor`` after the move, from ``pose`` before it."""
        out = np.array(pose, dtype=np.float64)
        out[:3, :3] = axis_rotation("y", math.radians(self.yaw_deg)) @ out[:3, :3]
        level_x = np.array([pose[0, 0], 0.0, pose[2, 0]])
        out[:3, 3] += level_x / np.linalg.norm(level_x) * self.shift_mm / 1000.0
        return out


class MovableSensor:
    """A simulated sensor that can be moved mid-take without the simulator knowing.

    Before :meth:`move_to` it is ``inner``; after, it reports what ``inner`` would see if it
    stood at the new pose: the world is moved by ``T_old · T_new⁻¹`` before ``inner`` sees it,
    so its sensor-frame joints are those of a sensor at ``T_new`` (its own error processes
    carry on). Exact for a move that keeps the vertical (:class:`SensorMove`): the simulator's
    processes about the world's vertical (facing bias, floor) then see the same world.
    ``T_world_from_sensor`` is the true pose (the new one after a move).
    """

    def __init__(self, inner: SimulatedSensor) -> None:
        self._inner = inner
        self._seen_from_old = np.eye(4)  # T_old · T_new⁻¹; identity until moved
        self._pose = np.array(inner.T_world_from_sensor, dtype=np.float64)
        self.moved = False

    def move_to(self, T_world_from_sensor: FloatArray) -> None:
        """Stand at ``T_world_from_sensor`` (4×4) from now on."""
        self._pose = np.array(T_world_from_sensor, dtype=np.float64)
        self._seen_from_old = self._inner.T_world_from_sensor @ invert(self._pose)
        self.moved = True

    @property
    def params(self) -> SensorParams:
        return self._inner.params

    @property
    def T_world_from_sensor(self) -> FloatArray:
        return self._pose

    @property
    def position_m(self) -> FloatArray:
        return self._pose[:3, 3].copy()

    def floor_plane(self) -> tuple[float, float, float, float]:
        """The floor (world y = 0) in the sensor frame at its true pose."""
        normal = self._pose[:3, :3].T @ np.array([0.0, 1.0, 0.0])
        return (float(normal[0]), float(normal[1]), float(normal[2]), float(self._pose[1, 3]))

    def observe(self, persons_world: FloatArray, t_s: float) -> list[Observation]:
        return self._inner.observe(apply(self._seen_from_old, persons_world), t_s)


@dataclass
class ViewTruth:
    """The true error of every view of a take: the latest per (sensor, person) for the oracle,
    and per (sensor, group) the sum of squared joint errors (m²) and the joints counted, from
    ``since_s`` (seconds into the take) on."""

    sensors: int
    since_s: float
    latest: dict[tuple[int, int], tuple[float, FloatArray]] = field(default_factory=dict)
    squares: FloatArray = field(init=False)
    counts: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        self.squares = np.zeros((self.sensors, len(GROUPS)))
        self.counts = np.zeros((self.sensors, len(GROUPS)))

    def add(self, capture: Capture, pose: FloatArray) -> None:
        """One frame of sensor ``capture.sensor`` standing (truly) at ``pose``."""
        k = capture.sensor
        for o in capture.observations:
            errors = view_errors(o.joints_m, o.mirrored, pose, capture.truth[o.person],
                                 o.true_joints)  # fmt: skip
            self.latest[(k, o.person)] = (capture.t_capture, errors)
            if capture.t_capture - T0 < self.since_s:
                continue
            for g, joints in enumerate(GROUPS.values()):
                part = errors[list(joints)]
                part = part[np.isfinite(part)]
                self.squares[k, g] += float(np.sum(part**2))
                self.counts[k, g] += part.size

    def rms_mm(self) -> FloatArray:
        """(sensors, groups) RMS true error (mm), NaN where none was seen."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.asarray(np.sqrt(self.squares / self.counts) * 1000, dtype=np.float64)

    def oracle(self, person: int, t_s: float) -> FloatArray | None:
        """The best correctly-labelled fresh view of ``person`` at fused instant ``t_s``."""
        fresh = [e for (_, who), (t, e) in self.latest.items()
                 if who == person and t_s - t < 1.5 / FPS]  # fmt: skip
        return best_view(fresh)


@dataclass
class Take:
    """One take's figures (mm unless said). mpjpe: method (:data:`FUSION`, ``oracle``, and
    ``single <sensor>``) → group (``all`` and :data:`GROUPS`) → MPJPE; wrong_labels: share of
    the learned hub's labelling decisions that are wrong; learned_mm / true_mm: sensor → group
    → learned error after the take / true RMS error over its last :data:`TRUTH_WINDOW_S`;
    spearman: their rank correlation pooled over sensors × groups (``pooled``) and per group
    across sensors (3 sensors or more)."""

    scenario: str
    model: str
    seed: int
    mpjpe: dict[str, dict[str, float]]
    wrong_labels: float
    learned_mm: dict[str, dict[str, float]]
    true_mm: dict[str, dict[str, float]]
    spearman: dict[str, float]


def _hubs(rig: SimulatedRig) -> dict[str, tuple[FusionHub, set[int]]]:
    """Every method's hub with the sensors it is fed: the fused ones all, each single one."""
    everyone = set(range(len(rig.names)))
    hubs = {label: (_new_hub(s, rig.names, rig.poses), everyone) for label, s in FUSION.items()}
    for k, name in enumerate(rig.names):
        hubs[f"single {name}"] = (_new_hub(BASE, [name], [rig.poses[k]]), {k})
    return hubs


def run_take(scenario: Scenario, seed: int, model: ErrorModel, label: str) -> Take:
    """One simulated capture (``label``: the error model's name in the results)."""
    rig = SimulatedRig(scenario, seed, KinectV2Params(), model)
    hubs = _hubs(rig)
    logs = {name: Log() for name in hubs}
    truth = ViewTruth(len(rig.names), scenario.duration_s - TRUTH_WINDOW_S)
    oracle: list[FloatArray] = []
    swapped: dict[tuple[str, int], dict[int, bool]] = {}
    for capture in rig.captures():
        truth.add(capture, rig.sensors[capture.sensor].T_world_from_sensor)
        swapped[(capture.name, capture.seq)] = {o.tracking_id: o.mirrored
                                                for o in capture.observations}  # fmt: skip
        for name, (hub, members) in hubs.items():
            if capture.sensor not in members:
                continue
            fused = feed(hub, capture)
            if fused is None:
                continue
            truth_at = rig.performer.joints_at(fused.t_s - T0)
            labels = label_decisions(hub, fused, swapped) if name == LEARNED else None
            persons = [(p.person_id, p.joints) for p in fused.persons]
            logs[name].add(logs[name].frames + 1, persons, truth_at, labels)
            if name == LEARNED:
                for person in range(truth_at.shape[0]):
                    chosen = truth.oracle(person, fused.t_s)
                    if chosen is not None:
                        oracle.append(chosen)
    mpjpe = {name: group_mpjpe(log.errors) for name, log in logs.items()}
    mpjpe[ORACLE] = group_mpjpe(oracle)
    learned = learned_groups(hubs[LEARNED][0], rig.names)
    true = {name: dict(zip(GROUPS, map(float, row), strict=True))
            for name, row in zip(rig.names, truth.rms_mm(), strict=True)}  # fmt: skip
    return Take(scenario.name, label, seed, mpjpe, logs[LEARNED].summary()["wrong_labels"],
                learned, true, correlations(learned, true))  # fmt: skip


def learned_groups(hub: FusionHub, names: Sequence[str]) -> dict[str, dict[str, float]]:
    """Sensor → group → the hub's learned error (mm), NaN for a sensor it never saw."""
    summary = hub.pipeline.errors.summary()
    nan = dict.fromkeys(GROUPS, math.nan)
    return {n: dict(summary[n].groups_mm) if n in summary else dict(nan) for n in names}


def correlations(
    learned: dict[str, dict[str, float]], true: dict[str, dict[str, float]]
) -> dict[str, float]:
    """Spearman of learned against true error: pooled over sensors × groups, and per group
    across sensors when there are 3 sensors or more (NaN otherwise)."""
    names = list(learned)
    pairs = [(learned[n][g], true[n][g]) for n in names for g in GROUPS]
    out = {"pooled": spearman([p[0] for p in pairs], [p[1] for p in pairs])}
    for g in GROUPS:
        rho = math.nan
        if len(names) >= 3:
            rho = spearman([learned[n][g] for n in names], [true[n][g] for n in names])
        out[g] = rho
    return out


@dataclass
class Move:
    """One move take. before / steady: the moved sensor's learned error (mm, per group) just
    before the move and its mean over the take's last 10 s; rise_s: seconds from the move until
    it is 90 % of the way from ``before`` to ``steady``; level_s: until it reaches 0.9 ×
    ``steady``; true_before / true_after: its views' true RMS error (mm) in the 10 s before the
    move and the last 10 s; registered_after: the same in the last 10 s through the pose fusion
    still has for it (the error fusion sees, and should learn); windows: per window of
    ``window_s``, MPJPE (mm, all joints) of the learned and the priors hub."""

    model: str
    seed: int
    moved: str
    before: dict[str, float]
    steady: dict[str, float]
    rise_s: dict[str, float]
    level_s: dict[str, float]
    true_before: dict[str, float]
    true_after: dict[str, float]
    registered_after: dict[str, float]
    windows: list[dict[str, float]]


def run_move(
    scenario: Scenario, seed: int, model: ErrorModel, label: str, bump: SensorMove,
    window_s: float = 5.0,
) -> Move:  # fmt: skip
    """One take of ``scenario`` in which sensor ``bump.sensor`` is moved by ``bump`` at
    ``bump.at_s`` while every hub keeps the pose it was registered with."""
    rig = SimulatedRig(scenario, seed, KinectV2Params(), model)
    moved = MovableSensor(rig.sensors[bump.sensor])
    rig.sensors[bump.sensor] = moved
    name = rig.names[bump.sensor]
    hubs = {m: _new_hub(FUSION[m], rig.names, rig.poses) for m in (LEARNED, PRIORS)}
    windows: dict[int, dict[str, list[FloatArray]]] = {}
    series: list[tuple[float, dict[str, float]]] = []
    truth = {when: ViewTruth(len(rig.names), 0.0) for when in ("before", "after", "registered")}
    for capture in rig.captures():
        t = capture.t_capture - T0
        if t >= bump.at_s and not moved.moved:
            moved.move_to(bump.pose_after(rig.poses[bump.sensor]))
        for when, lo, hi in (("before", bump.at_s - 10, bump.at_s),
                             ("after", scenario.duration_s - 10, math.inf)):  # fmt: skip
            if lo <= t < hi:
                truth[when].add(capture, rig.sensors[capture.sensor].T_world_from_sensor)
                if when == "after":
                    truth["registered"].add(capture, rig.poses[capture.sensor])
        for m, hub in hubs.items():
            fused = feed(hub, capture)
            if fused is None:
                continue
            log = Log()
            log.add(1, [(p.person_id, p.joints) for p in fused.persons],
                    rig.performer.joints_at(fused.t_s - T0))  # fmt: skip
            windows.setdefault(int((fused.t_s - T0) // window_s), {}).setdefault(m, []).extend(
                log.errors
            )
            if m == LEARNED and (not series or fused.t_s - T0 >= series[-1][0] + SAMPLE_EVERY_S):
                series.append((fused.t_s - T0, learned_groups(hub, [name])[name]))
    before = next(g for s, g in reversed(series) if s < bump.at_s)
    last = [v for s, v in series if s >= scenario.duration_s - 10]
    steady = {g: float(np.nanmean([v[g] for v in last])) for g in GROUPS}
    rise, level = rise_times(series, bump.at_s, before, steady)
    rows = [{"start_s": w * window_s, **{m: group_mpjpe(e)["all"] for m, e in by.items()}}
            for w, by in sorted(windows.items())]  # fmt: skip
    k = bump.sensor
    true_before = dict(zip(GROUPS, map(float, truth["before"].rms_mm()[k]), strict=True))
    true_after = dict(zip(GROUPS, map(float, truth["after"].rms_mm()[k]), strict=True))
    registered = dict(zip(GROUPS, map(float, truth["registered"].rms_mm()[k]), strict=True))
    return Move(label, seed, name, before, steady, rise, level, true_before, true_after,
                registered, rows)  # fmt: skip


def rise_times(
    series: list[tuple[float, dict[str, float]]], at_s: float, before: dict[str, float],
    steady: dict[str, float],
) -> tuple[dict[str, float], dict[str, float]]:  # fmt: skip
    """Per group, seconds after ``at_s`` until the learned error (``series``: (t, group → mm))
    is 90 % of the way from ``before`` to ``steady``, and until it is ≥ 0.9 × ``steady``
    (NaN: never)."""
    rise, level = {}, {}
    for g in GROUPS:
        after = [(s - at_s, v[g]) for s, v in series if s >= at_s]
        target = before[g] + 0.9 * (steady[g] - before[g])
        up = steady[g] >= before[g]
        rise[g] = next((d for d, v in after if (v >= target if up else v <= target)), math.nan)
        level[g] = next((d for d, v in after if v >= 0.9 * steady[g]), math.nan)
    return rise, level
