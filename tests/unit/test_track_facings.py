"""The mirror step's track facings, kept from the walking check of the step before.

``FusionPipeline._track_facings`` reuses the facings the walking check took at the end of the
last step when the tracks' skeletons are still those arrays; it must give exactly what
:func:`~skelfuse.fusion.anatomy.facing_directions` gives on the tracks now, whether a track
moved, turned over or was born since.
"""

from __future__ import annotations

import numpy as np

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.fusion.anatomy import facing_directions
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState

TRACKED = np.full(JOINT_COUNT, TrackingState.TRACKED, np.uint8)
SENSORS = {"a": np.array([0.0, 1.0, 3.0]), "b": np.array([3.0, 1.0, 0.0])}


def views_at(performer: ProceduralPerformer, t_s: float, rng: np.random.Generator) -> list[View]:
    people = performer.joints_at(t_s)
    return [
        View(name, p + 1, people[p] + rng.normal(0.0, 0.01, (JOINT_COUNT, 3)), TRACKED, where)
        for name, where in SENSORS.items()
        for p in range(len(people))
    ]


def fresh(pipeline: FusionPipeline, ids: list[int]) -> np.ndarray:
    return facing_directions(np.stack([pipeline.tracker.tracks[i].joints for i in ids]))


def test_kept_facings_are_the_facings_of_the_tracks_now() -> None:
    rng = np.random.default_rng(4)
    pipeline = FusionPipeline(FusionSettings())
    performer = ProceduralPerformer(2)
    kept = 0
    for k in range(40):
        t_s = 100.0 + k / 30
        pipeline.update(views_at(performer, t_s, rng), t_s)
        ids = sorted(pipeline.tracker.tracks)
        if k == 20:  # a track turned over (new array): the kept facing no longer applies
            pipeline.tracker.swap_sides(ids[0])
        tracks = [pipeline.tracker.tracks[i] for i in ids]
        kept += all(
            i in pipeline._facings and pipeline._facings[i][0] is t.joints
            for i, t in zip(ids, tracks, strict=True)
        )
        got = pipeline._track_facings(ids, tracks)
        assert got.tobytes() == fresh(pipeline, ids).tobytes()
    assert kept >= 30  # the usual case: the walking check's facings serve the next step
