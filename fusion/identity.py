"""Who is who: group each instant's views into persons and keep every person's id stable.

Each fusion step receives every sensor's bodies at one instant, already in the world frame
(:class:`~skelfuse.fusion.views.View`). :class:`PersonTracker` groups them into persons
(docs/fusion.md §3):

1. **Sticky**: a body a sensor keeps tracking (same sensor, same tracking id) stays with the
   person it belonged to, while it stays within twice the gate of that person's predicted
   position (constant-velocity prediction of the trunk).
2. **Assignment**: other bodies are matched to existing persons, one sensor at a time, by the
   Hungarian algorithm on midline-joint distance to the predicted position, gated (a sensor
   never gives one person two bodies).
3. **Birth**: bodies left over are grouped across sensors (gated) into new persons; a new
   person is published only after ``tracking.min_frames`` consecutive steps.
4. **No duplicates**: two persons whose views come from different sensors and whose trunks are
   within half the gate are one person seen twice; the younger is merged into the older.
5. **Death**: a person no sensor has seen for ``tracking.timeout_s`` is dropped.

The tracker keeps identity and motion only (where each person is, how fast they move, which
bodies are theirs); what fusion remembers per person (filter, bone lengths, mirror labels) is in
:mod:`skelfuse.fusion.pipeline`. State is in memory only; nothing here does I/O.

Trunks, association's measure of a person: two views, or a view and a track's prediction, are
the same person by the mean distance between the midline joints both have (:data:`TRUNK_JOINTS`,
(..., 5, 3) metres, world frame): the same whatever a sensor thinks is left or right. One
compiled loop computes it per pair (``(x² + y²) + z²`` and its square root per joint, the
distances summed joint after joint, divided by the count); :func:`sticky_distances` takes each
view's midline joints and its track's prediction from the stacked skeletons in the loop, with no
gathers first. After the fusion, :func:`moved` keeps each track's skeleton and smooths its trunk
velocity, the prediction's slope, in one loop over the persons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from skelfuse.fusion.mirror import PERMUTATION
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.views import View
from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId

FloatArray = npt.NDArray[np.float64]
ViewKey = tuple[str, int]
"""(sensor id, the sensor's own tracking id): one body as one sensor follows it."""

MAX_SPEED_MPS: Final = 3.0
"""Trunk speed used for prediction is clipped to this (a person, not a glitch)."""


@dataclass(slots=True)
class Track:
    """One person's identity and motion.

    joints: (25, 3) the last fused skeleton (world, metres), or the first view at birth.
    velocity: (3,) horizontal trunk velocity, m/s, for prediction.
    members: the (sensor, tracking id) bodies that were this person's at the last step.
    """

    person_id: int
    joints: FloatArray
    last_seen_s: float
    born_s: float
    hits: int = 0
    published: bool = False
    members: set[ViewKey] = field(default_factory=set)
    velocity: FloatArray = field(default_factory=lambda: np.zeros(3))
    fused_once: bool = False

    def predicted(self, t_s: float) -> FloatArray:
        """Joints moved by the trunk's velocity to ``t_s`` (association only)."""
        dt = min(max(t_s - self.last_seen_s, 0.0), 0.5)
        moved: FloatArray = self.joints + self.velocity * dt
        return moved


class PersonTracker:
    """Groups views into persons and keeps their ids (module docstring, steps 1–5)."""

    def __init__(self, settings: FusionSettings) -> None:
        self.settings = settings
        self.tracks: dict[int, Track] = {}
        self._next_id = 1

    def associate(self, views: list[View], t_s: float) -> dict[int, list[View]]:
        """Steps 1–4: the views of each person at ``t_s``, by person id (new persons included).

        A sensor gives a person at most one view. Persons born here are in :attr:`tracks`
        (unpublished); a person merged into an older one is gone from it.
        """
        clusters = self._assign(views, t_s)
        self._merge_duplicates(clusters)
        return clusters

    def confirm(self, clusters: dict[int, list[View]], t_s: float) -> set[int]:
        """Step 5 and publication, after the step's fusion: the ids published now.

        Each person seen counts a hit (published after ``tracking.min_frames`` in a row) and keeps
        its bodies for the sticky step; a person not seen starts its confirmation over if not
        yet published, and is dropped after ``tracking.timeout_s``.
        """
        for person_id, cluster in clusters.items():
            track = self.tracks[person_id]
            track.hits += 1
            track.members = {(v.sensor_id, v.tracking_id) for v in cluster}
            if track.hits >= self.settings.tracking.min_frames:
                track.published = True
        for person_id, track in list(self.tracks.items()):
            if person_id in clusters:
                continue
            if not track.published:
                track.hits = 0
            if t_s - track.last_seen_s > self.settings.tracking.timeout_s:
                del self.tracks[person_id]
        return {pid for pid in clusters if self.tracks[pid].published}

    def move(self, person_id: int, fused: FloatArray, t_s: float) -> None:
        """Keep a person's fused skeleton (25, 3) and its trunk velocity for prediction."""
        self.move_all([person_id], fused[None], t_s)

    def move_all(
        self, person_ids: list[int], fused: FloatArray, t_s: float
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`move` for many persons at once: ``fused`` (P, 25, 3), row p is ``person_ids[p]``.

        Element by element the arithmetic of one person alone, in one compiled loop
        (:func:`moved`).

        Returns:
            The tracks' new skeletons (P, 25, 3) and trunk velocities (P, 3), stacked (each
            track's own are those rows' values).
        """
        tracks = [self.tracks[person_id] for person_id in person_ids]
        if not tracks:
            return np.empty((0, JOINT_COUNT, 3)), np.empty((0, 3))
        kept, velocity, moving = moved(
            np.array([t.joints for t in tracks], dtype=np.float64),
            np.array([t.last_seen_s for t in tracks]),
            np.array([t.fused_once for t in tracks]),
            np.array([t.velocity for t in tracks], dtype=np.float64),
            fused,
            t_s,
            MAX_SPEED_MPS,
        )
        for p in moving.nonzero()[0].tolist():
            tracks[p].velocity = velocity[p]
        for track, row in zip(tracks, kept, strict=True):
            track.joints = row
            track.last_seen_s = t_s
            track.fused_once = True
        return kept, velocity

    def swap_sides(self, person_id: int) -> None:
        """Swap left and right in a person's skeleton (the whole track was mirrored)."""
        track = self.tracks[person_id]
        track.joints = track.joints[PERMUTATION]

    # --- steps 1-4 -----------------------------------------------------------------------------

    def _new_track(self, joints: FloatArray, t_s: float) -> Track:
        track = Track(self._next_id, joints.copy(), t_s, t_s)
        self._next_id += 1
        self.tracks[track.person_id] = track
        return track

    def _assign(self, views: list[View], t_s: float) -> dict[int, list[View]]:
        """Steps 1–3: each view to a person, by person id (new persons born here)."""
        tracks = list(self.tracks.values())
        clusters, seen, remaining = self._sticky(views, tracks, t_s)
        if not remaining:
            return clusters
        # The remaining views' midline joints, stacked once: the distances below are computed
        # for many pairs at a time.
        trunks = _trunks(remaining)
        index_of = {id(view): i for i, view in enumerate(remaining)}
        leftovers = self._hungarian(remaining, (trunks, index_of), tracks, t_s, clusters, seen)
        self._births(leftovers, (trunks, index_of), clusters, t_s)
        return clusters

    def _sticky(
        self, views: list[View], tracks: list[Track], t_s: float
    ) -> tuple[dict[int, list[View]], dict[int, set[str]], list[View]]:
        """1. Sticky membership: each body a sensor still tracks stays with its person within
        twice the gate of its prediction (every such view's distance in one call). Returns the
        clusters, the sensors each has a view from, and the views left to place."""
        owner: dict[ViewKey, Track] = {}
        for t in reversed(tracks):  # the first track holding a key wins
            for member in t.members:
                owner[member] = t
        sticky = [owner.get((view.sensor_id, view.tracking_id)) for view in views]
        with_track = [i for i, t in enumerate(sticky) if t is not None]
        distances: list[float] = [np.inf] * len(views)
        if with_track:
            row_of = {t.person_id: k for k, t in enumerate(tracks)}
            everyone = len(with_track) == len(views)  # the usual step: no gather, no scatter
            found = sticky_distances(
                np.array([views[i].joints_world for i in with_track], dtype=np.float64),
                (
                    np.array([t.joints for t in tracks], dtype=np.float64),
                    np.array([t.velocity for t in tracks], dtype=np.float64),
                    np.array([t.last_seen_s for t in tracks], dtype=np.float64),
                ),
                np.array([row_of[t.person_id] for t in sticky if t is not None], dtype=np.intp),
                t_s,
            )
            if everyone:
                distances = found.tolist()
            else:
                spread = np.full(len(views), np.inf)
                spread[with_track] = found
                distances = spread.tolist()
        sticky_gate = 2 * self.settings.tracking.gate_m
        clusters: dict[int, list[View]] = {}
        seen: dict[int, set[str]] = {}
        remaining: list[View] = []
        for view, track, distance in zip(views, sticky, distances, strict=True):
            if track is None or distance > sticky_gate:
                remaining.append(view)
                continue
            person_id = track.person_id
            sensors = seen.get(person_id)
            if sensors is None:
                seen[person_id] = {view.sensor_id}
                clusters[person_id] = [view]
            elif view.sensor_id in sensors:
                remaining.append(view)
            else:
                clusters[person_id].append(view)
                sensors.add(view.sensor_id)
        return clusters, seen, remaining

    def _hungarian(
        self,
        remaining: list[View],
        stacked: tuple[FloatArray, dict[int, int]],
        tracks: list[Track],
        t_s: float,
        clusters: dict[int, list[View]],
        seen: dict[int, set[str]],
    ) -> list[View]:
        """2. Hungarian assignment of the ``remaining`` views (``stacked``: their trunks and
        each one's row there, by id) to existing tracks, sensor by sensor, within the gate;
        adds to ``clusters`` and ``seen``; returns the views left over."""
        gate = self.settings.tracking.gate_m
        trunks, index_of = stacked
        predicted = _predicted_trunks(tracks, t_s)
        leftovers: list[View] = []
        for sensor_id in sorted({v.sensor_id for v in remaining}):
            mine = [v for v in remaining if v.sensor_id == sensor_id]
            free = [k for k, t in enumerate(tracks) if sensor_id not in seen.get(t.person_id, ())]
            if not free:
                leftovers.extend(mine)
                continue
            mine_trunks = trunks[[index_of[id(v)] for v in mine]]
            cost = trunk_distances(mine_trunks[:, None], predicted[free][None, :])
            cost_finite = np.where(np.isfinite(cost), cost, 1e6)
            rows, cols = linear_sum_assignment(cost_finite)
            taken = set()
            for r, c in zip(rows, cols, strict=True):
                if cost[r, c] <= gate:
                    person_id = tracks[free[c]].person_id
                    clusters.setdefault(person_id, []).append(mine[r])
                    seen.setdefault(person_id, set()).add(sensor_id)
                    taken.add(r)
            leftovers.extend(v for i, v in enumerate(mine) if i not in taken)
        return leftovers

    def _births(
        self,
        leftovers: list[View],
        stacked: tuple[FloatArray, dict[int, int]],
        clusters: dict[int, list[View]],
        t_s: float,
    ) -> None:
        """3. Births: the ``leftovers`` grouped across sensors (gated) into new persons, added
        to ``clusters`` (``stacked``: as :meth:`_hungarian`)."""
        trunks, index_of = stacked
        new_clusters: list[list[View]] = []
        for view in leftovers:
            best, best_distance = None, self.settings.tracking.gate_m
            own = trunks[index_of[id(view)]][None]
            for cluster in new_clusters:
                if any(v.sensor_id == view.sensor_id for v in cluster):
                    continue
                others = trunks[[index_of[id(v)] for v in cluster]]
                distance = float(np.mean(trunk_distances(own, others)))
                if distance <= best_distance:
                    best, best_distance = cluster, distance
            if best is None:
                new_clusters.append([view])
            else:
                best.append(view)
        for cluster in new_clusters:
            track = self._new_track(cluster[0].joints_world, t_s)
            clusters[track.person_id] = cluster

    def _merge_duplicates(self, clusters: dict[int, list[View]]) -> None:
        """4. Merge persons that are one person seen by disjoint sets of sensors (older id wins)."""
        half_gate = self.settings.tracking.gate_m / 2
        ids = sorted(clusters)
        sensors = {pid: {v.sensor_id for v in clusters[pid]} for pid in ids}
        for i, older in enumerate(ids):
            if older not in clusters:
                continue
            for younger in ids[i + 1 :]:
                if younger not in clusters:
                    continue
                if sensors[older] & sensors[younger]:
                    continue
                a, b = clusters[older], clusters[younger]
                # Every pair (x in a, y in b), x outer, in one call: the mean sees the same list.
                pairs = trunk_distances(_trunks(a)[:, None], _trunks(b)[None, :])
                distance = np.mean(pairs.ravel())
                if distance <= half_gate:
                    a.extend(b)
                    sensors[older] |= sensors[younger]
                    del clusters[younger]
                    young, old = self.tracks[younger], self.tracks[older]
                    if young.published and not old.published:
                        old.published = True
                    del self.tracks[younger]


def _trunks(views: list[View]) -> FloatArray:
    """(N, 5, 3) float64 the views' midline joints (:data:`TRUNK_JOINTS`), metres."""
    if not views:
        return np.empty((0, len(TRUNK_JOINTS), 3))
    joints = np.array([v.joints_world for v in views], dtype=np.float64)
    # take: the fancy index's values, ~3× faster on a step's views (2.9 → 1.0 µs at 24).
    trunks: FloatArray = joints.take(TRUNK_JOINTS, axis=1)
    return trunks


def _predicted_trunks(tracks: list[Track], t_s: float) -> FloatArray:
    """(T, 5, 3) each track's :meth:`Track.predicted` midline joints at ``t_s``, the same floats."""
    if not tracks:
        return np.empty((0, len(TRUNK_JOINTS), 3))
    dts = [min(max(t_s - t.last_seen_s, 0.0), 0.5) for t in tracks]
    joints = np.array([t.joints for t in tracks], dtype=np.float64).take(TRUNK_JOINTS, axis=1)
    moves = np.array([t.velocity for t in tracks], dtype=np.float64) * np.array(dts)[:, None]
    moved: FloatArray = joints + moves[:, None, :]
    return moved


# --- Trunks: association's measure of a person, and how a track's trunk moves --------------------


IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

TRUNK_JOINTS: Final = np.array(
    [JointId.SPINE_BASE, JointId.SPINE_MID, JointId.SPINE_SHOULDER, JointId.NECK, JointId.HEAD]
)
"""Joints on the body's midline: the same whatever a sensor thinks is left or right."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now, off any latency-bound path."""
    points = np.zeros((1, 5, 3))
    trunk_distances(points, points)
    index = np.zeros(1, dtype=np.intp)
    sticky_distances(np.zeros((1, 25, 3)), (np.zeros((1, 25, 3)), np.zeros((1, 3)), np.zeros(1)),
                     index, 0.0)  # fmt: skip
    joints = np.zeros((1, 25, 3))
    moved(joints, np.zeros(1), np.ones(1, bool), np.zeros((1, 3)), joints, 1.0, 3.0)


def trunk_distance(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Mean distance between the midline joints two skeletons both have (metres); ``inf``
    when they share fewer than two.

    Args:
        a, b: (25, 3) joints, metres, same frame; NaN where unknown.
    """
    pa = np.asarray(a, dtype=np.float64)[TRUNK_JOINTS]
    pb = np.asarray(b, dtype=np.float64)[TRUNK_JOINTS]
    return float(trunk_distances(pa, pb))


def trunk_distances(a: FloatArray, b: FloatArray) -> FloatArray:
    """Per pair, the mean distance (metres) between the midline joints both have (finite in
    both), ``inf`` where they share fewer than two.

    Args:
        a, b: (..., K, 3) midline joints, metres; their leading axes broadcast (views against
            tracks: (N, 1, K, 3) and (1, T, K, 3)).

    Returns:
        (...) float64, the broadcast leading shape.
    """
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    lead = a.shape[:-2]
    pairs = math.prod(lead)
    out = np.empty(pairs)
    _distances_loop(plain(a.reshape(pairs, *a.shape[-2:])), plain(b.reshape(pairs, *b.shape[-2:])),
                    out)  # fmt: skip
    return out.reshape(lead)


def sticky_distances(
    views: FloatArray,
    tracks: tuple[FloatArray, FloatArray, FloatArray],
    rows: IntArray,
    t_s: float,
) -> FloatArray:
    """Each view's trunk distance to its track's prediction at ``t_s`` (the track's joints
    moved by its velocity times ``min(max(t_s − last seen, 0), 0.5)``).

    Args:
        views: (N, 25, 3) metres, world; tracks: (T, 25, 3) each track's joints, (T, 3) its
            trunk velocity (m/s) and (T,) when it was last seen (seconds); rows: (N,) each
            view's track.

    Returns:
        (N,) float64 metres (``inf``: fewer than two midline joints in common).
    """
    joints, velocities, last_seen = tracks
    out = np.empty(views.shape[0])
    _sticky_loop(
        plain(views),
        (plain(joints), plain(velocities), plain(last_seen)),
        plain(rows, np.intp),
        float(t_s),
        plain(TRUNK_JOINTS, np.intp),
        out,
    )
    return out


@jit
def _sticky_loop(
    views: FloatArray,
    tracks: tuple[FloatArray, FloatArray, FloatArray],
    rows: IntArray,
    t_s: float,
    trunk_joints: IntArray,
    out: FloatArray,
) -> None:
    """:func:`sticky_distances` into ``out``."""
    joints, velocities, last_seen = tracks
    size = len(trunk_joints)
    a = np.empty((views.shape[0], size, 3))
    b = np.empty((views.shape[0], size, 3))
    for n in range(views.shape[0]):
        r = rows[n]
        # Track.predicted's step: min(max(t − last seen, 0), 0.5) as Python's max and min.
        dt = t_s - last_seen[r]
        if dt < 0.0:
            dt = 0.0
        if dt > 0.5:
            dt = 0.5
        for k in range(size):
            for c in range(3):
                a[n, k, c] = views[n, trunk_joints[k], c]
                b[n, k, c] = joints[r, trunk_joints[k], c] + velocities[r, c] * dt
    _distances_loop(a, b, out)


@jit
def _distances_loop(a: FloatArray, b: FloatArray, out: FloatArray) -> None:
    """:func:`trunk_distances` of (M, K, 3) pairs into ``out`` (M,)."""
    for m in range(a.shape[0]):
        total = 0.0
        count = 0
        for j in range(a.shape[1]):
            finite = True
            for k in range(3):
                if not (np.isfinite(a[m, j, k]) and np.isfinite(b[m, j, k])):
                    finite = False
            if not finite:
                continue
            dx = a[m, j, 0] - b[m, j, 0]
            dy = a[m, j, 1] - b[m, j, 1]
            dz = a[m, j, 2] - b[m, j, 2]
            total += np.sqrt((dx * dx + dy * dy) + dz * dz)
            count += 1
        out[m] = np.inf if count < 2 else total / max(count, 1)


def moved(
    joints: FloatArray,
    last_seen_s: FloatArray,
    fused_once: BoolArray,
    velocities: FloatArray,
    fused: FloatArray,
    t_s: float,
    max_speed_mps: float,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The tracks after a fusion at ``t_s``: the velocity's difference quotient of SpineBase
    (horizontal only), smoothed ``0.6 old + 0.4 new``, its speed ``√((x² + y²) + z²)`` clipped
    at ``max_speed_mps``; a joint kept where the fusion has none.

    Args:
        joints: (P, 25, 3) each track's skeleton before (world, metres); last_seen_s: (P,)
            when each was last fused (s); fused_once: (P,) whether it has been;
            velocities: (P, 3) its trunk velocity (m/s); fused: (P, 25, 3) this fusion,
            NaN where it has no joint; t_s: the instant (s); max_speed_mps: the speed clip.

    Returns:
        (P, 25, 3) the skeletons kept (the fused joint, the old one where there is none),
        (P, 3) the new velocities (the old ones where a track does not move), (P,) which
        tracks moved (fused before, within 0.5 s, with a SpineBase then and now).
    """
    count = joints.shape[0]
    kept = np.empty((count, joints.shape[1], 3))
    velocity = np.empty((count, 3))
    moving = np.empty(count, dtype=np.bool_)
    _move_loop(
        plain(joints),
        plain(last_seen_s),
        plain(fused_once, np.bool_),
        plain(velocities),
        plain(fused),
        float(t_s),
        float(max_speed_mps),
        kept,
        velocity,
        moving,
    )
    return kept, velocity, moving


@jit
def _move_loop(
    joints: FloatArray,
    last_seen_s: FloatArray,
    fused_once: BoolArray,
    velocities: FloatArray,
    fused: FloatArray,
    t_s: float,
    max_speed_mps: float,
    kept: FloatArray,
    velocity: FloatArray,
    moving: BoolArray,
) -> None:
    """:func:`moved` into ``kept``, ``velocity`` and ``moving``."""
    for p in range(joints.shape[0]):
        dt = t_s - last_seen_s[p]
        roots = True  # a SpineBase in both skeletons
        for k in range(3):
            roots = roots and np.isfinite(fused[p, 0, k]) and np.isfinite(joints[p, 0, k])
        moving[p] = fused_once[p] and dt > 0.0 and dt < 0.5 and roots
        if moving[p]:
            for k in range(3):
                new = 0.0 if k == 1 else (fused[p, 0, k] - joints[p, 0, k]) / dt
                velocity[p, k] = 0.6 * velocities[p, k] + 0.4 * new
            x, y, z = velocity[p, 0], velocity[p, 1], velocity[p, 2]
            speed = np.sqrt((x * x + y * y) + z * z)
            if speed > max_speed_mps:
                scale = max_speed_mps / speed
                for k in range(3):
                    velocity[p, k] = velocity[p, k] * scale
        else:
            for k in range(3):
                velocity[p, k] = velocities[p, k]
        for j in range(joints.shape[1]):
            for k in range(3):
                value = fused[p, j, k]
                kept[p, j, k] = value if np.isfinite(value) else joints[p, j, k]
