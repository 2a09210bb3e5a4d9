"""People across views and over time: one fused skeleton and one stable id per person.

Each fusion step receives every sensor's bodies at one instant, already in the world frame
(:class:`View`). :class:`PersonTracker` groups them into persons, keeps ids stable and fuses
each person (docs/fusion.md):

1. **Sticky**: a body a sensor keeps tracking (same sensor, same tracking id) stays with the
   person it belonged to, while it stays within twice the gate of that person's predicted
   position (constant-velocity prediction of the trunk).
2. **Assignment**: other bodies are matched to existing persons, one sensor at a time, by the
   Hungarian algorithm on midline-joint distance to the predicted position, gated (a sensor
   never gives one person two bodies).
3. **Birth**: bodies left over are grouped across sensors (gated) into new persons; a new
   person is published only after ``track_min_frames`` consecutive steps.
4. **No duplicates**: two persons whose views come from different sensors and whose trunks are
   within half the gate are one person seen twice; the younger is merged into the older.
5. **Death**: a person no sensor has seen for ``track_timeout_s`` is dropped.

Then, per person: mirrored views are swapped back (:mod:`fusion.mirror`), each joint of each
view gets a weight (tracking state × bone length × range of motion × facing × distance,
:mod:`fusion.confidence`), views are fused (:func:`fusion.weighted.fuse_views`), filtered over
time (:mod:`fusion.filters`) and given the person's reference bone lengths. Reference lengths
are set through the API or estimated online from good views (:class:`BoneModel`).

State is in memory only; nothing here does I/O.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from skelfuse.fusion.confidence import (
    align_yaw,
    bone_length_factors,
    distance_factors,
    facing_cosines,
    facing_direction,
    facing_directions,
    facing_factors,
    propagate,
    range_of_motion_factors,
)
from skelfuse.fusion.filters import JointFilter, filter_all, make_filter
from skelfuse.fusion.mirror import MAX_VIEWS, PERMUTATION, choose_labellings
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.weighted import (
    TRUNK_JOINTS,
    enforce_bone_lengths,
    fuse_views_batch,
    project_bone_lengths,
    state_weights,
    trunk_distance,
)
from skelfuse.protocol.skeleton import BONE_MIRROR_PERMUTATION, BONES, JOINT_COUNT, TrackingState

FloatArray = npt.NDArray[np.float64]
BONE_COUNT = len(BONES)
_BONE_PARENT = np.array([p for p, _ in BONES])
_BONE_CHILD = np.array([c for _, c in BONES])
_BONE_MIRROR = np.array(BONE_MIRROR_PERMUTATION)
MAX_SPEED_MPS = 3.0
"""Trunk speed used for prediction is clipped to this (a person, not a glitch)."""
GOOD_VIEW_COS = 0.5
"""A view feeds the online bone-length estimate only if the person faces it within 60°."""
_NO_POSITION = np.full(3, np.nan)
_MIN_SHARE = 0.05
"""A view is a source of a joint when it carries this share of its weight (as ``contributors``)."""


def nanmedian_axis(data: FloatArray, axis: int) -> FloatArray:
    """``np.nanmedian`` along ``axis`` (the same values: mean of the two middle ones), faster.

    All-NaN slices give NaN without a warning.
    """
    ordered = np.sort(data, axis=axis)  # NaN last
    count = np.isfinite(data).sum(axis=axis, keepdims=True)
    low = np.take_along_axis(ordered, np.maximum((count - 1) // 2, 0), axis=axis)
    high = np.take_along_axis(ordered, count // 2, axis=axis)
    median = np.where(count > 0, (low + high) / 2.0, np.nan)
    result: FloatArray = np.squeeze(median, axis=axis)
    return result


@dataclass(frozen=True, slots=True)
class View:
    """One sensor's body at the fusion instant.

    joints_world: (25, 3) float64, metres, world frame, NaN where NotTracked.
    states: (25,) uint8 TrackingState.
    sensor_position: (3,) float64, where the sensor stands in the world (metres), if known.
    """

    sensor_id: str
    tracking_id: int
    joints_world: FloatArray
    states: npt.NDArray[np.uint8]
    sensor_position: FloatArray | None = None


@dataclass(frozen=True, slots=True)
class FusedPerson:
    """One person's fused skeleton (world frame, metres; NaN and confidence 0 where unknown).

    joint_sources: (25,) int64 bitmask per joint: bit k set when ``sources[k]`` contributed at
        least 5 % of that joint's weight.
    mirrored: the sensors whose view of this person was swapped back (left ↔ right).
    """

    person_id: int
    joints: FloatArray
    confidence: FloatArray
    sources: tuple[str, ...]
    views: tuple[View, ...]
    joint_sources: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros(JOINT_COUNT, dtype=np.int64)
    )
    mirrored: tuple[str, ...] = ()


BoneSource = Literal["set", "estimated", "none"]


class BoneModel:
    """A person's reference bone lengths: set by hand, or estimated online.

    The online estimate is, per bone, the median of the last ``window`` observations from good
    views (both ends Tracked, the person facing the sensor within 60°, after mirror
    correction). A bone that good views have not shown ``min_samples`` times yet (hand tips and
    thumbs, often) takes the median of any view where both ends are Tracked instead. With
    ``symmetric``, a left bone and its right counterpart share their observations: people are
    left-right symmetric to a percent or two, and twice the samples settle the estimate sooner.
    The estimate is refreshed every step while it settles, then every ``_REFRESH_EVERY`` steps.
    """

    _REFRESH_EVERY = 10

    def __init__(
        self,
        window: int = 300,
        min_samples: int = 30,
        symmetric: bool = True,
        lock_samples: int | None = None,
    ) -> None:
        self.set_lengths: FloatArray | None = None
        self.min_samples = min_samples
        self.symmetric = symmetric
        self.lock_samples = lock_samples
        self._locked = np.zeros(BONE_COUNT, dtype=bool)
        self._samples: deque[FloatArray] = deque(maxlen=window)
        self._fallback: deque[FloatArray] = deque(maxlen=window)
        self._estimate = np.full(BONE_COUNT, np.nan)
        self._since_update = 0

    @property
    def source(self) -> BoneSource:
        if self.set_lengths is not None:
            return "set"
        return "estimated" if np.isfinite(self._estimate).any() else "none"

    @property
    def estimate(self) -> FloatArray:
        """(24,) online estimate, metres; NaN for bones without enough observations."""
        return self._estimate.copy()

    def reference(self) -> FloatArray:
        """(24,) the lengths fusion uses: the set ones, else the estimate (NaN: unknown)."""
        return self.set_lengths.copy() if self.set_lengths is not None else self.estimate

    def observe(self, lengths: FloatArray, fallback: FloatArray | None = None) -> None:
        """Add one step's observed lengths.

        Args:
            lengths: (24,) metres from good views, NaN for bones not observed well.
            fallback: (24,) metres from any view with both ends Tracked, or None.
        """
        good = bool(np.isfinite(lengths).any())
        spare = fallback is not None and bool(np.isfinite(fallback).any())
        if not (good or spare):
            return
        if good:
            self._samples.append(lengths)
        if spare:
            assert fallback is not None
            self._fallback.append(fallback)
        self._since_update += 1
        settling = len(self._samples) < 2 * self.min_samples
        if settling or self._since_update >= self._REFRESH_EVERY:
            self._since_update = 0
            estimate, counts = self._median(self._samples)
            missing = ~np.isfinite(estimate)
            if missing.any():
                estimate[missing] = self._median(self._fallback)[0][missing]
            self._estimate = np.where(self._locked, self._estimate, estimate)
            if self.lock_samples is not None:
                self._locked |= counts >= self.lock_samples

    def mirror(self) -> None:
        """Swap left and right in the online samples (the track they came from was mirrored)."""
        for samples in (self._samples, self._fallback):
            swapped = [sample[_BONE_MIRROR] for sample in samples]
            samples.clear()
            samples.extend(swapped)
        self._estimate = self._estimate[_BONE_MIRROR]
        self._locked = self._locked[_BONE_MIRROR]

    def _median(self, samples: deque[FloatArray]) -> tuple[FloatArray, FloatArray]:
        """Per-bone median of ``samples`` (NaN where fewer than ``min_samples``) and the
        observations behind it, per bone (with ``symmetric``: the mean of a left/right pair's)."""
        if not samples:
            return np.full(BONE_COUNT, np.nan), np.zeros(BONE_COUNT)
        data = np.stack(samples)
        sides = 1
        if self.symmetric:
            data = np.concatenate([data, data[:, _BONE_MIRROR]], axis=0)
            sides = 2
        counts = np.isfinite(data).sum(axis=0) / sides
        median = np.where(counts >= self.min_samples, nanmedian_axis(data, axis=0), np.nan)
        return median, counts  # all-NaN bones stay NaN


@dataclass(slots=True)
class _Track:
    person_id: int
    joints: FloatArray
    last_seen_s: float
    born_s: float
    filter: JointFilter
    bones: BoneModel
    hits: int = 0
    published: bool = False
    members: set[tuple[str, int]] = field(default_factory=set)
    velocity: FloatArray = field(default_factory=lambda: np.zeros(3))
    mirror_memory: dict[tuple[str, int], bool] = field(default_factory=dict)
    fused_once: bool = False
    backward_since_s: float | None = None
    walk_swaps: int = 0

    def predicted(self, t_s: float) -> FloatArray:
        """Joints moved by the trunk's velocity to ``t_s`` (association only)."""
        dt = min(max(t_s - self.last_seen_s, 0.0), 0.5)
        moved: FloatArray = self.joints + self.velocity * dt
        return moved


class PersonTracker:
    """Groups views into persons and keeps their ids; call :meth:`update` once per step."""

    def __init__(self, settings: FusionSettings | None = None) -> None:
        self.settings = settings or FusionSettings()
        self._tracks: dict[int, _Track] = {}
        self._next_id = 1
        self.default_bone_lengths: FloatArray | None = None
        """(24,) lengths every new person starts with as "set" (None: estimate online)."""

    @property
    def track_count(self) -> int:
        return len(self._tracks)

    def reset(self) -> None:
        self._tracks.clear()

    # --- reference bone lengths (REST: server/routes_fusion.py) --------------------------------

    def person_ids(self) -> list[int]:
        """Ids of the persons currently published."""
        return sorted(pid for pid, t in self._tracks.items() if t.published)

    def bone_model(self, person_id: int) -> BoneModel | None:
        track = self._tracks.get(person_id)
        return None if track is None else track.bones

    def set_bone_lengths(self, person_id: int, lengths: FloatArray | None) -> bool:
        """Set (or with None, clear back to automatic) a person's reference lengths.

        Args:
            lengths: (24,) metres in :data:`BONES` order, or None.

        Returns:
            False if there is no such person.
        """
        track = self._tracks.get(person_id)
        if track is None:
            return False
        track.bones.set_lengths = None if lengths is None else np.array(lengths, dtype=float)
        return True

    # --- the step ------------------------------------------------------------------------------

    def update(self, views: list[View], t_s: float) -> list[FusedPerson]:
        """Fuse the views of one instant; returns the published persons, by id."""
        clusters = self._associate(views, t_s)
        self._merge_duplicates(clusters)
        published: list[FusedPerson] = []
        items = [(self._tracks[pid], cluster) for pid, cluster in sorted(clusters.items())]
        fused_persons = self._fuse_all(items, t_s)
        for (track, cluster), person in zip(items, fused_persons, strict=True):
            track.hits += 1
            track.members = {(v.sensor_id, v.tracking_id) for v in cluster}
            if track.hits >= self.settings.track_min_frames:
                track.published = True
            if track.published and person is not None:
                published.append(person)

        # Deaths; a track that missed a step starts its confirmation over if unpublished.
        for person_id, track in list(self._tracks.items()):
            if person_id in clusters:
                continue
            if not track.published:
                track.hits = 0
            if t_s - track.last_seen_s > self.settings.track_timeout_s:
                del self._tracks[person_id]
        return published

    def _new_track(self, joints: FloatArray, t_s: float) -> _Track:
        s = self.settings
        person_id = self._next_id
        self._next_id += 1
        bones = BoneModel(
            s.bone_estimate_window,
            s.bone_estimate_min_samples,
            s.bone_estimate_symmetric,
            s.bone_estimate_lock_samples,
        )
        if self.default_bone_lengths is not None:
            bones.set_lengths = self.default_bone_lengths.copy()
        track = _Track(
            person_id,
            joints.copy(),
            t_s,
            t_s,
            self._make_filter(),
            bones,
        )
        self._tracks[person_id] = track
        return track

    def _make_filter(self) -> JointFilter:
        s = self.settings
        return make_filter(
            s.filter,
            min_cutoff_hz=s.one_euro_min_cutoff_hz,
            beta=s.one_euro_beta,
            d_cutoff_hz=s.one_euro_d_cutoff_hz,
            accel_std=s.kalman_accel_std,
            meas_std_m=s.kalman_meas_std_m,
            predict_s=s.kalman_predict_s,
        )

    def _check_walking_direction(self, track: _Track, t_s: float) -> None:
        """Swap a whole track that walks backwards for too long (``mirror_walk_check_s``).

        A track born mirrored (every sensor seeing the person from the side or behind) stays
        mirrored, since each view is labelled to agree with it and its own facing, reversed,
        makes the back views look like front ones. The walking direction is the one cue that
        does not depend on the labels. The swap takes effect from the next step: the track's
        skeleton and every view's remembered labelling are swapped, the filter restarts (it
        would otherwise sweep the limbs across), the online bone samples swap sides.
        """
        s = self.settings
        if s.mirror_walk_check_s <= 0 or not s.use_mirror_correction:
            return
        speed = float(np.linalg.norm(track.velocity))
        backwards = False
        if speed >= s.mirror_walk_min_speed_mps:
            facing = facing_direction(track.joints)
            backwards = bool(np.isfinite(facing).all()) and (
                float(np.dot(facing, track.velocity)) < -0.5 * speed
            )
        if not backwards:
            track.backward_since_s = None
            return
        if track.backward_since_s is None:
            track.backward_since_s = t_s
            return
        if t_s - track.backward_since_s < s.mirror_walk_check_s:
            return
        track.joints = track.joints[PERMUTATION]
        track.mirror_memory = {key: not m for key, m in track.mirror_memory.items()}
        track.filter = self._make_filter()
        track.bones.mirror()
        track.backward_since_s = None
        track.walk_swaps += 1

    def _associate(self, views: list[View], t_s: float) -> dict[int, list[View]]:
        gate = self.settings.association_gate_m
        clusters: dict[int, list[View]] = {}
        remaining: list[View] = []
        predicted = {pid: t.predicted(t_s) for pid, t in self._tracks.items()}

        # 1. Sticky membership (every view's distance to its track in one pass).
        owner: dict[tuple[str, int], _Track] = {}
        for t in reversed(self._tracks.values()):  # the first track holding a key wins
            for member in t.members:
                owner[member] = t
        sticky = [owner.get((view.sensor_id, view.tracking_id)) for view in views]
        with_track = [i for i, t in enumerate(sticky) if t is not None]
        distances = np.full(len(views), np.inf)
        if with_track:
            distances[with_track] = _trunk_distances(
                np.stack([views[i].joints_world[TRUNK_JOINTS] for i in with_track]),
                np.stack([predicted[sticky[i].person_id][TRUNK_JOINTS] for i in with_track]),  # type: ignore[union-attr]
            )
        for view, track, distance in zip(views, sticky, distances, strict=True):
            if track is None or distance > 2 * gate:
                remaining.append(view)
                continue
            cluster = clusters.setdefault(track.person_id, [])
            if any(v.sensor_id == view.sensor_id for v in cluster):
                remaining.append(view)
            else:
                cluster.append(view)

        # 2. Hungarian assignment to existing tracks, sensor by sensor.
        leftovers: list[View] = []
        for sensor_id in sorted({v.sensor_id for v in remaining}):
            mine = [v for v in remaining if v.sensor_id == sensor_id]
            free = [
                t
                for t in self._tracks.values()
                if not any(v.sensor_id == sensor_id for v in clusters.get(t.person_id, []))
            ]
            if not free:
                leftovers.extend(mine)
                continue
            cost = np.array(
                [[trunk_distance(v.joints_world, predicted[t.person_id]) for t in free]
                 for v in mine]
            )  # fmt: skip
            cost_finite = np.where(np.isfinite(cost), cost, 1e6)
            rows, cols = linear_sum_assignment(cost_finite)
            taken = set()
            for r, c in zip(rows, cols, strict=True):
                if cost[r, c] <= gate:
                    clusters.setdefault(free[c].person_id, []).append(mine[r])
                    taken.add(r)
            leftovers.extend(v for i, v in enumerate(mine) if i not in taken)

        # 3. Births: group leftovers across sensors.
        new_clusters: list[list[View]] = []
        for view in leftovers:
            best, best_distance = None, gate
            for cluster in new_clusters:
                if any(v.sensor_id == view.sensor_id for v in cluster):
                    continue
                distance = float(
                    np.mean([trunk_distance(view.joints_world, v.joints_world) for v in cluster])
                )
                if distance <= best_distance:
                    best, best_distance = cluster, distance
            if best is None:
                new_clusters.append([view])
            else:
                best.append(view)
        for cluster in new_clusters:
            track = self._new_track(cluster[0].joints_world, t_s)
            clusters[track.person_id] = cluster
        return clusters

    def _merge_duplicates(self, clusters: dict[int, list[View]]) -> None:
        """Merge persons that are one person seen by disjoint sets of sensors (older id wins)."""
        half_gate = self.settings.association_gate_m / 2
        ids = sorted(clusters)
        for i, older in enumerate(ids):
            if older not in clusters:
                continue
            for younger in ids[i + 1 :]:
                if younger not in clusters:
                    continue
                a, b = clusters[older], clusters[younger]
                if {v.sensor_id for v in a} & {v.sensor_id for v in b}:
                    continue
                distance = np.mean(
                    [trunk_distance(x.joints_world, y.joints_world) for x in a for y in b]
                )
                if distance <= half_gate:
                    a.extend(b)
                    del clusters[younger]
                    young, old = self._tracks[younger], self._tracks[older]
                    if young.published and not old.published:
                        old.published = True
                    del self._tracks[younger]

    # --- fusing the persons ----------------------------------------------------------------------

    def _fuse_all(
        self, items: list[tuple[_Track, list[View]]], t_s: float
    ) -> list[FusedPerson | None]:
        """Fuse every person of this step; each as if alone, every per-view term in one pass.

        Views of all persons are stacked (N views, person ``person_of[i]``, its ``slot_of[i]``-th
        view); per-person sums use a (P, S_max, ...) block padded after the real views with
        NaN views of weight 0, which leaves every sum and product as it is for one person.
        """
        if not items:
            return []
        s = self.settings
        tracks = [track for track, _ in items]
        clusters = [cluster[:MAX_VIEWS] for _, cluster in items]
        counts = [len(cluster) for cluster in clusters]
        flat = [view for cluster in clusters for view in cluster]
        total, persons, widest = len(flat), len(items), max(counts)
        person_of = np.repeat(np.arange(persons), counts)
        starts = np.cumsum([0, *counts])
        slot_of = np.arange(total) - starts[person_of]
        joints = np.stack([v.joints_world for v in flat]).astype(np.float64)
        states = np.stack([v.states for v in flat])
        sensors = np.stack(
            [_NO_POSITION if v.sensor_position is None else v.sensor_position for v in flat]
        ).astype(np.float64)
        track_joints = np.stack([track.joints for track in tracks])
        fused_once = np.array([track.fused_once for track in tracks])
        track_facing = facing_directions(track_joints)

        # Mirrored views: swap labels back before anything looks at left or right.
        mirrored = np.zeros(total, dtype=bool)
        rom: FloatArray | None = None
        if s.use_mirror_correction:
            keys = [(v.sensor_id, v.tracking_id) for v in flat]
            previous = np.array(
                [
                    int(tracks[p].mirror_memory.get(k, -1))
                    for p, k in zip(person_of, keys, strict=True)
                ]
            )
            mirrored, both_rom = choose_labellings(
                joints,
                sensors,
                counts,
                [track.joints if track.fused_once else None for track in tracks],
                track_facing,
                previous,
                geometry_weight_m=s.mirror_geometry_weight_m,
                hysteresis_m=s.mirror_hysteresis_m,
                track_weight=s.mirror_track_weight,
                anatomy_weight_m=s.mirror_anatomy_weight_m,
                rom_scale_deg=s.rom_scale_deg,
                need_rom=s.use_range_of_motion,
            )
            for p, track in enumerate(tracks):
                lo, hi = starts[p], starts[p + 1]
                track.mirror_memory = {
                    k: bool(m) for k, m in zip(keys[lo:hi], mirrored[lo:hi], strict=True)
                }
            if mirrored.any():
                joints[mirrored] = joints[mirrored][:, PERMUTATION]
                states[mirrored] = states[mirrored][:, PERMUTATION]
            if both_rom is not None:
                rom = both_rom[np.arange(total), mirrored.astype(np.intp)]

        # Body-based confidence, propagated outward from SpineBase.
        weights = state_weights(states, s.state_weights)
        local = np.ones(joints.shape[:2])
        if s.use_bone_length:
            references = np.stack([track.bones.reference() for track in tracks])
            if np.isfinite(references).any():  # an unknown reference gives factors of 1
                local *= bone_length_factors(joints, references[person_of], s.bone_length_scale_m)
        if s.use_range_of_motion:
            local *= rom if rom is not None else range_of_motion_factors(joints, s.rom_scale_deg)
        weights = weights * propagate(local)

        def fuse(joints: FloatArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
            padded_joints = np.full((persons, widest, JOINT_COUNT, 3), np.nan)
            padded_joints[person_of, slot_of] = joints
            padded_weights = np.zeros((persons, widest, JOINT_COUNT))
            padded_weights[person_of, slot_of] = weights
            return fuse_views_batch(padded_joints, padded_weights)

        fused, confidence = fuse(joints, weights)

        # Facing and distance: per view, from where the person stands and faces.
        facing = track_facing
        if not fused_once.all():
            facing = np.where(fused_once[:, None], track_facing, facing_directions(fused))
        spine = np.zeros((persons, widest, 2, 3))
        spine[person_of, slot_of, 0] = np.where(np.isfinite(joints[:, 0]), joints[:, 0], 0.0)
        spine[person_of, slot_of, 1] = np.isfinite(joints[:, 0])
        sums = spine.sum(axis=1)  # np.nanmean of each person's SpineBase, in the same order
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_spine = sums[:, 0] / sums[:, 1]
        fused_spine_ok = np.isfinite(fused[:, 0]).all(axis=-1, keepdims=True)
        body = np.where(fused_spine_ok, fused[:, 0], mean_spine)
        view_body = body[person_of]
        cosines = facing_cosines(facing[person_of], view_body, sensors)
        per_view = np.ones(total)
        if s.use_facing:
            per_view *= facing_factors(
                cosines, s.facing_power, s.facing_floor, s.facing_back_factor
            )
        if s.use_distance:
            per_view *= distance_factors(view_body, sensors, s.distance_best_m, s.distance_scale_m)
        if s.correct_view_yaw:
            for p in range(persons):
                lo, hi = starts[p], starts[p + 1]
                if hi - lo > 1:
                    joints[lo:hi] = _corrected_yaw(joints[lo:hi], cosines[lo:hi], s.yaw_max_deg)
        if s.use_facing or s.use_distance or s.correct_view_yaw:
            weights = weights * per_view[:, None]
            fused, confidence = fuse(joints, weights)
        if s.outlier_scale_m > 0:
            several = np.array(counts)[person_of] > 1
            if several.any():
                # One Cauchy re-weighting pass (fusion.weighted.robust_reweight) per person.
                d = np.linalg.norm(joints - fused[person_of], axis=-1)
                factor = np.where(np.isfinite(d), 1.0 / (1.0 + (d / s.outlier_scale_m) ** 2), 1.0)
                weights = np.where(several[:, None], weights * factor, weights)
                fused, confidence = fuse(joints, weights)

        self._observe_bones(tracks, joints, states, cosines, person_of, slot_of, widest)

        # Which views carried each joint (fusion.weighted.contributors), as source bitmasks.
        final = np.zeros((persons, widest, JOINT_COUNT))
        final[person_of, slot_of] = np.where(np.isfinite(joints).all(-1), weights, 0.0)
        total_weight = final.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(total_weight[:, None] > 0, final / total_weight[:, None], 0.0)
        carries = (share >= _MIN_SHARE) & (final > 0)

        for p, track in enumerate(tracks):
            self._update_motion(track, fused[p], t_s)
            self._check_walking_direction(track, t_s)
        alive = [p for p in range(persons) if np.isfinite(fused[p]).any()]
        filtered = filter_all([tracks[p].filter for p in alive], fused[alive], t_s)
        outputs = dict(zip(alive, filtered, strict=True))
        if s.enforce_bone_lengths and alive:
            references = np.stack([tracks[p].bones.reference() for p in alive])
            fitted = [i for i in range(len(alive)) if np.isfinite(references[i]).any()]
            if fitted:
                skeletons = np.stack([outputs[alive[i]] for i in fitted])
                if s.bone_length_fit == "chain":
                    enforced = enforce_bone_lengths(skeletons, references[fitted])
                else:
                    enforced = project_bone_lengths(
                        skeletons, references[fitted], iterations=s.bone_fit_iterations
                    )
                for k, i in enumerate(fitted):
                    outputs[alive[i]] = enforced[k]

        out: list[FusedPerson | None] = []
        for p, (track, cluster) in enumerate(zip(tracks, clusters, strict=True)):
            if p not in outputs:
                out.append(None)
                continue
            sources = tuple(sorted({v.sensor_id for v in cluster}))
            slots = np.array([sources.index(v.sensor_id) for v in cluster], dtype=np.int64)
            joint_sources = np.bitwise_or.reduce(
                carries[p, : len(cluster)].astype(np.int64) << slots[:, None], axis=0
            )
            lo = starts[p]
            out.append(
                FusedPerson(
                    person_id=track.person_id,
                    joints=outputs[p],
                    confidence=confidence[p],
                    sources=sources,
                    views=tuple(cluster),
                    joint_sources=joint_sources,
                    mirrored=tuple(
                        sorted(
                            v.sensor_id
                            for v, m in zip(cluster, mirrored[lo : lo + len(cluster)], strict=True)
                            if m
                        )
                    ),
                )
            )
        return out

    @staticmethod
    def _observe_bones(
        tracks: list[_Track],
        joints: FloatArray,
        states: npt.NDArray[np.uint8],
        cosines: FloatArray,
        person_of: npt.NDArray[np.intp],
        slot_of: npt.NDArray[np.intp],
        widest: int,
    ) -> None:
        """Feed each online bone-length estimate with this step's good views of its person."""
        estimating = np.array([track.bones.set_lengths is None for track in tracks])
        if not estimating.any():
            return
        good_view = np.isfinite(cosines) & (cosines >= GOOD_VIEW_COS)
        tracked = states == TrackingState.TRACKED
        both_tracked = tracked[:, _BONE_PARENT] & tracked[:, _BONE_CHILD]
        lengths = np.linalg.norm(joints[:, _BONE_CHILD] - joints[:, _BONE_PARENT], axis=-1)
        usable = both_tracked & np.isfinite(lengths)
        # (persons, views, bones, 2): good views only, then any view.
        padded = np.full((len(tracks), widest, BONE_COUNT, 2), np.nan)
        padded[person_of, slot_of, :, 0] = np.where(usable & good_view[:, None], lengths, np.nan)
        padded[person_of, slot_of, :, 1] = np.where(usable, lengths, np.nan)
        observed = np.isfinite(padded[..., 1]).any(axis=(1, 2)) & estimating
        if not observed.any():
            return
        per_bone = nanmedian_axis(padded, axis=1)  # (persons, bones, 2)
        for p in np.flatnonzero(observed):
            tracks[p].bones.observe(per_bone[p, :, 0], per_bone[p, :, 1])

    @staticmethod
    def _update_motion(track: _Track, fused: FloatArray, t_s: float) -> None:
        """Keep the last fused skeleton and the trunk's velocity for prediction."""
        dt = t_s - track.last_seen_s
        moving = np.isfinite(fused[0]).all() and np.isfinite(track.joints[0]).all()
        if track.fused_once and 0 < dt < 0.5 and moving:
            velocity = (fused[0] - track.joints[0]) / dt
            velocity[1] = 0.0
            track.velocity = 0.6 * track.velocity + 0.4 * velocity
            speed = float(np.linalg.norm(track.velocity))
            if speed > MAX_SPEED_MPS:
                track.velocity *= MAX_SPEED_MPS / speed
        track.joints = np.where(np.isfinite(fused), fused, track.joints)
        track.last_seen_s = t_s
        track.fused_once = True


def _corrected_yaw(joints: FloatArray, cosines: FloatArray, max_deg: float) -> FloatArray:
    """One person's views turned to the facing of the views seen most squarely.

    The person's facing from the views seen most squarely (least turned by their sensor's
    bias), then every view turned to it (``correct_view_yaw``).
    """
    frontal = np.nan_to_num(np.abs(cosines), nan=0.5) ** 4 + 1e-6
    own = np.stack([facing_direction(v) for v in joints])
    usable = np.isfinite(own).all(axis=1)
    if usable.any():
        mean = (frontal[usable, None] * own[usable]).sum(axis=0)
        norm = float(np.linalg.norm(mean))
        if norm > 1e-6:
            return align_yaw(joints, mean / norm, max_deg)
    return joints


def _trunk_distances(a: FloatArray, b: FloatArray) -> FloatArray:
    """:func:`fusion.weighted.trunk_distance` of many pairs: a, b (M, 5, 3) midline → (M,)."""
    both = np.isfinite(a).all(-1) & np.isfinite(b).all(-1)
    diff = a - b
    d = np.sqrt((diff * diff).sum(-1))
    count = both.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(both, d, 0.0).sum(-1) / count
    result: FloatArray = np.where(count < 2, np.inf, mean)
    return result
