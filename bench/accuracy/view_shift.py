"""Lead or lag of the fused output against the views themselves: no ground truth needed.

What a real recording allows: the sensors' own reported trajectories, each view at its capture
time (the server's clock, as fusion places it), against the fused trajectory. The shift ``τ`` is
the one minimising the mean squared distance between each view's joint at its capture time
``t_c`` and the fused joint at ``t_c + τ`` (the fused output linearly interpolated between its
instants), after removing each (sensor, joint coordinate)'s constant offset over the take (a
sensor's bias, a side view's lean, a camera's depth error are errors, not delays). Positive: the
fused output is behind the views; negative: it leads them (an extrapolation overshooting).

Each view is the body fusion made part of the person at the nearest fused instant, with left
and right swapped back where fusion swapped them (``FusedPerson.mirrored``), and only its
Tracked joints (an Inferred joint is the sensor's guess). A monocular camera's view (``rgb``) is
compared across its lines of sight only: its depth is its weakest axis and its depth errors
follow the pose, so they would read as a shift. Samples within half a second of a change of the
person followed (a birth, a track reborn) or of a jump of the person (a clip looping back to
its start) are left out. Shifts are those of
``bench.accuracy.lag`` (a 2 ms grid, refined by a parabola), and only view samples whose every
shifted instant lies inside the fused take count, so every shift is scored on the same samples.

Shapes: joints (25, 3) world metres; times seconds (server clock).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from bench.accuracy.lag import SHIFTS_S, best_shift
from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.rig_errors import GROUPS
from skelfuse.protocol.skeleton import MIRROR_PERMUTATION, JointId, TrackingState
from skelfuse.protocol.transform import apply
from skelfuse.protocol.wire import Frame

FloatArray = npt.NDArray[np.float64]
_MIRROR = list(MIRROR_PERMUTATION)
MAX_FUSED_GAP_S = 0.1
"""The fused output is not interpolated across a gap longer than this (seconds)."""
MONOCULAR = frozenset({"rgb"})
"""Sensor types whose depth is their weakest axis, and whose depth errors follow the pose (a
monocular placement): compared across their lines of sight only."""
SWITCH_MARGIN_S = 0.5
"""Samples this close (seconds) to a change of the person followed, or a jump, are left out."""
JUMP_M = 0.3
"""A SpineBase moving more than this in one step (metres; 9 m/s at 30 fps) has jumped."""


@dataclass
class Take:
    """What one hub published and was fed, for the views-based measure.

    fused_t: fused instants (seconds); fused: (25, 3) joints of the person followed at each
    (NaN where not reported); members: per fused instant, sensor id → (tracking id, swapped
    back); views: per sensor, (capture time on the server clock, tracking id → world joints
    (25, 3) with NotTracked / Inferred joints NaN).
    """

    fused_t: list[float] = field(default_factory=list)
    person: list[int] = field(default_factory=list)
    """The id of the person followed at each fused instant (0: nobody)."""
    fused: list[FloatArray] = field(default_factory=list)
    members: list[dict[str, tuple[int, bool]]] = field(default_factory=list)
    views: dict[str, list[tuple[float, dict[int, FloatArray]]]] = field(default_factory=dict)
    positions: dict[str, FloatArray] = field(default_factory=dict)
    """Each sensor's position in the world (3,), metres: its lines of sight start there."""
    across_only: set[str] = field(default_factory=set)
    """Sensors compared across their lines of sight only (monocular cameras, :data:`MONOCULAR`)."""

    def add_view(self, sensor_id: str, t_server_s: float, frame: Frame, pose: FloatArray,
                 sensor_type: str = "kinect_v2") -> None:  # fmt: skip
        """One sensor frame as fusion received it: its bodies moved into the world by ``pose``
        (``T_world_from_sensor``, 4×4), Tracked joints only."""
        if sensor_type in MONOCULAR:
            self.across_only.add(sensor_id)
        bodies: dict[int, FloatArray] = {}
        for body in frame.bodies:
            world = apply(pose, body.joints_m)
            world[body.states != TrackingState.TRACKED] = np.nan
            bodies[body.tracking_id] = world
        self.views.setdefault(sensor_id, []).append((t_server_s, bodies))
        self.positions[sensor_id] = np.asarray(pose[:3, 3], dtype=np.float64)

    def add_fused(self, fused: FusedFrame) -> None:
        """One fused frame: the person with the most sources (a single performer)."""
        self.fused_t.append(fused.t_s)
        if not fused.persons:
            self.person.append(0)
            self.fused.append(np.full((25, 3), np.nan))
            self.members.append({})
            return
        person = max(fused.persons, key=lambda p: len(p.sources))
        self.person.append(person.person_id)
        self.fused.append(np.asarray(person.joints, dtype=np.float64))
        self.members.append(
            {v.sensor_id: (v.tracking_id, v.sensor_id in person.mirrored) for v in person.views}
        )


def steady(take: Take, at: FloatArray, margin_s: float = SWITCH_MARGIN_S) -> npt.NDArray[np.bool_]:
    """Whether each instant ``at`` (M,) is at least ``margin_s`` from every change of the
    person followed (a birth, a track lost and reborn) and every jump of a view's or the
    output's SpineBase by more than :data:`JUMP_M` in one step (a clip looping back to its
    start): those stretches are a start, not a delay."""
    times, ids = np.asarray(take.fused_t), np.asarray(take.person)
    changes = [times[1:][ids[1:] != ids[:-1]]]
    tracks = [(times, np.stack(take.fused)[:, JointId.SPINE_BASE])] if take.fused else []
    for frames in take.views.values():
        for tracking_id in {i for _, bodies in frames for i in bodies}:
            kept = [(t, b[tracking_id][JointId.SPINE_BASE]) for t, b in frames if tracking_id in b]
            tracks.append((np.array([t for t, _ in kept]), np.stack([p for _, p in kept])))
    for t, spine in tracks:
        steps = np.linalg.norm(np.diff(spine, axis=0), axis=-1)
        changes.append(t[1:][steps > JUMP_M])
    every = np.concatenate(changes)
    if not len(every):
        return np.ones(len(at), dtype=np.bool_)
    return np.asarray(np.min(np.abs(at[:, None] - every[None]), axis=1) > margin_s)


def view_samples(take: Take) -> dict[str, tuple[FloatArray, FloatArray]]:
    """Per sensor, its capture times (M,) and its person's body there (M, 25, 3), swapped back
    where fusion swapped it, from the fused instant nearest each capture."""
    times = np.asarray(take.fused_t)
    out: dict[str, tuple[FloatArray, FloatArray]] = {}
    for sensor, frames in take.views.items():
        kept_t: list[float] = []
        kept: list[FloatArray] = []
        for t_c, bodies in frames:
            nearest = int(np.argmin(np.abs(times - t_c))) if len(times) else -1
            if nearest < 0 or abs(times[nearest] - t_c) > MAX_FUSED_GAP_S:
                continue
            member = take.members[nearest].get(sensor)
            if member is None or member[0] not in bodies:
                continue
            joints = bodies[member[0]]
            kept_t.append(t_c)
            kept.append(joints[_MIRROR] if member[1] else joints)
        if kept:
            out[sensor] = (np.asarray(kept_t), np.stack(kept))
    return out


def fused_at(times: FloatArray, fused: FloatArray, at: FloatArray) -> FloatArray:
    """The fused joints (N, 25, 3) at instants ``times`` (N,), linearly interpolated at ``at``
    (M,): (M, 25, 3), NaN outside the take or across a gap over :data:`MAX_FUSED_GAP_S`."""
    index = np.clip(np.searchsorted(times, at), 1, len(times) - 1)
    before, after = times[index - 1], times[index]
    alpha = ((at - before) / np.maximum(after - before, 1e-9))[:, None, None]
    out = fused[index - 1] * (1.0 - alpha) + fused[index] * alpha
    bad = (at < times[0]) | (at > times[-1]) | (after - before > MAX_FUSED_GAP_S)
    out[bad] = np.nan
    return np.asarray(out, dtype=np.float64)


def across_sight(diff: FloatArray, sight: FloatArray) -> FloatArray:
    """``diff`` (..., M, J, 3) without its component along the unit lines of sight ``sight``
    (M, J, 3; zeros: the whole difference): what a camera measures well (a monocular view's
    depth is its weakest, and its depth errors follow the pose: they would read as a shift)."""
    along = np.sum(diff * sight, axis=-1, keepdims=True)
    return np.asarray(diff - along * sight, dtype=np.float64)


def shift_against_views(take: Take, groups: Mapping[str, tuple[int, ...]] = GROUPS,
                        settle_s: float = 0.0) -> dict[str, float]:  # fmt: skip
    """Per joint group, the best-fit shift (ms) of the fused output behind the views (module
    docstring); NaN for a group with nothing to compare. ``settle_s``: view samples in the
    take's first seconds are left out (a person's birth, the filter settling)."""
    times = np.asarray(take.fused_t)
    if len(times) < 10:
        return dict.fromkeys(groups, math.nan)
    fused = np.stack(take.fused)
    margin = float(np.max(np.abs(SHIFTS_S)))
    samples = {}
    for sensor, (t_c, joints) in view_samples(take).items():
        inside = (t_c - margin >= times[0] + settle_s) & (t_c + margin <= times[-1])
        inside &= steady(take, t_c)
        if inside.sum() >= 10:
            samples[sensor] = (t_c[inside], joints[inside])
    out: dict[str, float] = {}
    for group, joints_of in groups.items():
        chosen = list(joints_of)
        errors = np.zeros(len(SHIFTS_S))
        for sensor, (t_c, joints) in samples.items():
            seen = joints[:, chosen]
            sight = seen - take.positions[sensor]
            sight = np.nan_to_num(sight / np.linalg.norm(sight, axis=-1, keepdims=True))
            if sensor not in take.across_only:
                sight = np.zeros_like(sight)  # the whole difference
            moved = np.stack([fused_at(times, fused, t_c + shift)[:, chosen] for shift in SHIFTS_S])
            # The same samples for every shift: a joint missing on either side at any shift is
            # left out of all of them.
            usable = np.isfinite(moved).all(axis=(0, -1)) & np.isfinite(seen).all(axis=-1)
            if usable.sum() < 10:
                continue
            mask = usable[None, ..., None]
            diff = across_sight(np.where(mask, moved - seen[None], 0.0), sight)
            count = np.maximum(usable.sum(axis=0), 1)[None, None, :, None]
            centred = np.where(mask, diff - diff.sum(axis=1, keepdims=True) / count, 0.0)
            errors += np.sum(centred**2, axis=(1, 2, 3))
        out[group] = best_shift(errors) * 1000 if errors.any() else math.nan
    return out
