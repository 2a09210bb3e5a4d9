"""People across views and over time: one fused skeleton and one stable id per person.

Each fusion step receives every sensor's bodies at one instant, already in the world frame
(:class:`View`). :class:`PersonTracker` groups them into persons and keeps ids stable:

1. **Sticky**: a body a sensor keeps tracking (same sensor, same tracking id) stays with the
   person it belonged to, while it stays within twice the gate of that person.
2. **Assignment**: other bodies are matched to existing persons, one sensor at a time, by the
   Hungarian algorithm on midline-joint distance, gated (a sensor never gives one person two
   bodies).
3. **Birth**: bodies left over are grouped across sensors (gated) into new persons.
4. **Death**: a person no sensor has seen for ``track_timeout_s`` is dropped.

A new person is published only after ``track_min_frames`` consecutive steps, so a one-frame
glitch never appears as a ghost. State is in memory only; nothing here does I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from server.fusion import fuse_views, state_weights, trunk_distance
from server.settings import FusionSettings

FloatArray = npt.NDArray[np.float64]


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
    """One person's fused skeleton (world frame, metres; NaN and confidence 0 where unknown)."""

    person_id: int
    joints: FloatArray
    confidence: FloatArray
    sources: tuple[str, ...]
    views: tuple[View, ...]


@dataclass(slots=True)
class _Track:
    person_id: int
    joints: FloatArray
    last_seen_s: float
    hits: int = 0
    published: bool = False
    members: set[tuple[str, int]] = field(default_factory=set)


class PersonTracker:
    """Groups views into persons and keeps their ids; call :meth:`update` once per step."""

    def __init__(self, settings: FusionSettings | None = None) -> None:
        self.settings = settings or FusionSettings()
        self._tracks: dict[int, _Track] = {}
        self._next_id = 1

    @property
    def track_count(self) -> int:
        return len(self._tracks)

    def reset(self) -> None:
        self._tracks.clear()

    def update(self, views: list[View], t_s: float) -> list[FusedPerson]:
        """Fuse the views of one instant; returns the published persons, by id."""
        gate = self.settings.association_gate_m
        clusters: dict[int, list[View]] = {}
        remaining: list[View] = []

        # 1. Sticky membership.
        for view in views:
            key = (view.sensor_id, view.tracking_id)
            track = next((t for t in self._tracks.values() if key in t.members), None)
            if track is None or trunk_distance(view.joints_world, track.joints) > 2 * gate:
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
                [[trunk_distance(v.joints_world, t.joints) for t in free] for v in mine]
            )
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
            person_id = self._next_id
            self._next_id += 1
            self._tracks[person_id] = _Track(person_id, cluster[0].joints_world, t_s)
            clusters[person_id] = cluster

        # Fuse each cluster and update its track.
        published: list[FusedPerson] = []
        for person_id, cluster in sorted(clusters.items()):
            track = self._tracks[person_id]
            joints = np.stack([v.joints_world for v in cluster])
            weights = state_weights(
                np.stack([v.states for v in cluster]), self.settings.state_weights
            )
            fused, confidence = fuse_views(joints, weights)
            track.joints = np.where(np.isfinite(fused), fused, track.joints)
            track.last_seen_s = t_s
            track.hits += 1
            track.members = {(v.sensor_id, v.tracking_id) for v in cluster}
            if track.hits >= self.settings.track_min_frames:
                track.published = True
            if track.published and np.isfinite(fused).any():
                published.append(
                    FusedPerson(
                        person_id=person_id,
                        joints=fused,
                        confidence=confidence,
                        sources=tuple(sorted({v.sensor_id for v in cluster})),
                        views=tuple(cluster),
                    )
                )

        # 4. Deaths; a track that missed a step starts its confirmation over if unpublished.
        for person_id, track in list(self._tracks.items()):
            if person_id in clusters:
                continue
            if not track.published:
                track.hits = 0
            if t_s - track.last_seen_s > self.settings.track_timeout_s:
                del self._tracks[person_id]
        return published
