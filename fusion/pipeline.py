"""The fusion pipeline: every sensor's bodies at one instant in, one skeleton per person out.

:meth:`FusionPipeline.step` reads top to bottom as the data flows (docs/fusion.md):

1. **align in time**: each sensor's body frames interpolated to the instant
   (:func:`skelfuse.fusion.sensors.body_arrays_at`);
2. **world frame**: each body moved by its sensor's ``T_world_from_sensor``
   (:func:`skelfuse.fusion.world_views.views_at`, all sensors in one pass);
3. **associate**: views grouped into persons with stable ids (:mod:`skelfuse.fusion.identity`);
4. **mirror labels**: views whose left and right are swapped are swapped back
   (:mod:`skelfuse.fusion.labels`, :mod:`skelfuse.fusion.mirror`);
5. **per-joint confidence**: bone length × range of motion, propagated along the body
   (:mod:`skelfuse.fusion.confidence`), over each view's joint's error variance learned from
   the rig, by where its sensor stands relative to the person, its tracking state and distance
   (:mod:`skelfuse.fusion.rig_errors`), with a Student-t factor for a view far off the others;
6. **weighted fusion**: the weighted mean of the views (:mod:`skelfuse.fusion.weigh`);
   the confidence apps receive with each joint (:func:`~skelfuse.fusion.confidence.
   joint_confidence`);
7. **filter**: each person's joints smoothed over time (:mod:`skelfuse.fusion.filters`);
8. **bone-length fit**: the filtered skeleton given the person's reference bone lengths
   (:mod:`skelfuse.fusion.bones`). The fit comes after the filter so that the lengths apps
   receive are exactly the reference ones.

Step 5 runs three times around step 6: the bins need to know where the person stands and
faces, which the first fusion (with the body terms alone) tells for a person seen the first
time, and the robust factor needs the fusion under the learned variances. All are
:func:`skelfuse.fusion.weigh.weigh_and_fuse`'s, one compiled call in the usual step. After it,
each view's leave-one-out residuals teach its sensor's learned error (``RigErrors.observe``).

Every step is a pure function on arrays except the state each person carries from one instant
to the next: its identity and motion (:class:`~skelfuse.fusion.identity.PersonTracker`) and what
fusion remembers of it (:class:`PersonMemory`). In memory only; nothing here does I/O or reads a
clock.
"""

from __future__ import annotations

from collections.abc import Iterable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from typing import Final, Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import facing_directions
from skelfuse.fusion.bone_fit import project_bone_lengths
from skelfuse.fusion.bones import (
    BoneModel,
    observe_bone_lengths,
    references_of,
)
from skelfuse.fusion.filters import JointFilter, Stacks, filter_all, make_filter
from skelfuse.fusion.identity import PersonTracker, Track
from skelfuse.fusion.labels import LabelDoubt, Labels, label_views
from skelfuse.fusion.mirror import walking_backwards, walking_backwards_now
from skelfuse.fusion.mirror_scores import MAX_VIEWS
from skelfuse.fusion.priors import KINECT_V2, SensorPrior, priors_of
from skelfuse.fusion.rig_errors import Observed, RigErrors
from skelfuse.fusion.sensors import SensorState
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.views import FusedPerson, View, fused_persons
from skelfuse.fusion.weigh import Learned, ViewBatch, Weighed, weigh_and_fuse
from skelfuse.fusion.world_views import PoseLookup, views_at

__all__ = ["NO_TIMER", "STAGES", "FusionPipeline", "PersonMemory", "PoseLookup", "StageTimer"]

FloatArray = npt.NDArray[np.float64]

STAGES: Final = (
    "views", "update", "associate", "labels", "weights", "bones observe", "walking check",
    "filter", "bone fit",
)  # fmt: skip
"""The stages a :class:`StageTimer` hears of, in order: steps 1–2 (each sensor's bodies at the
instant, in the world frame: also the engine's late-sensor path), then ``update``, the whole of
steps 3–8, around the others: 3, 4, 5–6, the online bone observation, the walking check, 7
and 8."""


class StageTimer(Protocol):
    """Told when each stage of a fusion step starts and ends: :meth:`stage` is entered as the
    stage ``name`` (one of :data:`STAGES`) starts and left as it ends. The benchmarks time the
    stages with one; the pipeline itself reads no clock."""

    def stage(self, name: str) -> AbstractContextManager[object]:
        """A context manager around the stage ``name``."""
        ...


class _NoTimer:
    """The default :class:`StageTimer`: hears nothing (one shared, reusable null context)."""

    _nothing: Final = nullcontext()

    def stage(self, name: str) -> AbstractContextManager[object]:
        return self._nothing


NO_TIMER: Final[StageTimer] = _NoTimer()
"""The pipeline's timer unless one is given: nothing is timed."""


@dataclass(slots=True)
class PersonMemory:
    """What fusion carries over for one person: filter, bone lengths, mirror labels."""

    filter: JointFilter
    bones: BoneModel
    labels: Labels = field(default_factory=dict)
    backward_since_s: float | None = None
    walk_swaps: int = 0
    """How often the whole person was swapped for walking backwards (diagnostics, tests)."""
    doubt: LabelDoubt = field(default_factory=LabelDoubt)
    """Running evidence against the labels (``mirror.redecide``, fusion.labels.redecide)."""


class FusionPipeline:
    """The state fusion keeps between instants, and the step (module docstring)."""

    def __init__(self, settings: FusionSettings, timer: StageTimer = NO_TIMER) -> None:
        self.settings = settings
        self.timer = timer
        """Told when each stage starts and ends (:class:`StageTimer`; by default nothing): the
        benchmarks' stage timing, settable at any time."""
        self.tracker = PersonTracker(settings)
        self.memories: dict[int, PersonMemory] = {}
        self._default_bone_lengths: FloatArray | None = None
        self._facings: dict[int, tuple[FloatArray, FloatArray]] = {}
        """Per person, the track joints (the array object) the walking check last took the
        facing of, and that facing: the next step's mirror labels start from the same one."""
        self._filter_stacks: Stacks = {}
        """The filters' stacked states of the last step (:func:`filter_all` reuses them)."""
        self.errors = RigErrors(settings)
        """Each sensor's error learned from the rig (steps 5–6 weigh by it)."""

    def step(
        self, sensors: Iterable[SensorState], pose_of: PoseLookup, t_s: float, gap_s: float
    ) -> tuple[list[FusedPerson], list[View]]:
        """Fuse the instant ``t_s``: the published persons by id, and every view used."""
        with self.timer.stage("views"):  # 1. align in time, 2. world frame
            views = views_at(sensors, pose_of, t_s, gap_s)
        return self.update(views, t_s), views

    def update(self, views: list[View], t_s: float) -> list[FusedPerson]:
        """Steps 3–8 on the views of one instant (world frame); the published persons, by id."""
        timer = self.timer
        with timer.stage("update"):
            with timer.stage("associate"):
                clusters = self.tracker.associate(views, t_s)  # 3. associate
            ids = sorted(clusters)
            outputs = self._fuse(ids, clusters, t_s) if ids else {}
            published = self.tracker.confirm(clusters, t_s)
            for person_id in list(self.memories):
                if person_id not in self.tracker.tracks:
                    del self.memories[person_id]
            return [outputs[pid] for pid in sorted(published) if pid in outputs]

    def _fuse(
        self, ids: list[int], clusters: dict[int, list[View]], t_s: float
    ) -> dict[int, FusedPerson]:
        """Steps 4–8 for the persons ``ids`` (sorted), whose views ``clusters`` holds."""
        s, timer = self.settings, self.timer
        for person_id in ids:
            if person_id not in self.memories:
                self.memories[person_id] = self._new_memory()
        tracks = [self.tracker.tracks[pid] for pid in ids]
        memories = [self.memories[pid] for pid in ids]
        batch = ViewBatch.of([clusters[pid][:MAX_VIEWS] for pid in ids], s.weights.sensor_priors)
        track_facing = self._track_facings(ids, tracks)
        with timer.stage("labels"):  # 4. mirror labels
            mirrored, rom = self._label(batch, ids, tracks, memories, track_facing, t_s)
        with timer.stage("weights"):  # 5. per-joint confidence, 6. weighted fusion
            priors = self._priors(batch)
            rows = self.errors.rows_of(
                [v.sensor_id for v in batch.views], priors or [KINECT_V2] * len(batch.views)
            )
            batch.depth_ratios = self.errors.depth_ratios(rows)
            weighed = weigh_and_fuse(
                batch,
                rom,
                references_of([m.bones for m in memories]),
                track_facing,
                [t.fused_once for t in tracks],
                s,
                priors,
                Learned(rows, self.errors.variance),
                np.array([t.joints for t in tracks], dtype=np.float64),
            )
            self.errors.observe(
                Observed(
                    batch.joints, weighed.weights, weighed.variances, rows, weighed.bins,
                    weighed.between, batch.starts, batch.sensors,
                ),
                t_s,
            )  # fmt: skip
        with timer.stage("bones observe"):
            observe_bone_lengths(
                [m.bones for m in memories], batch.joints, batch.states, weighed.cosines,
                batch.person_of, batch.slot_of, batch.widest,
            )  # fmt: skip
        moved = self.tracker.move_all(ids, weighed.fused, t_s)
        with timer.stage("walking check"):  # each looks at its own person only
            self._check_walking_directions(ids, t_s, moved)
        # The ufunc's own reduce: what .any() calls after a Python wrapper's checks.
        seen: list[bool] = np.logical_or.reduce(np.isfinite(weighed.fused), axis=(1, 2)).tolist()
        alive = [p for p, any_joint in enumerate(seen) if any_joint]
        with timer.stage("filter"):  # 7. filter
            skeletons = self._filter(memories, weighed.fused, alive, len(ids), t_s)
        with timer.stage("bone fit"):  # 8. bone-length fit
            self._fit_bones(memories, skeletons, alive)
        return self._outputs(ids, alive, skeletons, weighed, batch, mirrored)

    def _priors(self, batch: ViewBatch) -> list[SensorPrior] | None:
        """Each view's sensor prior (fusion/priors.py), or None with the priors off."""
        if not self.settings.weights.sensor_priors:
            return None
        return priors_of([v.sensor_type for v in batch.views])

    def _label(
        self,
        batch: ViewBatch,
        ids: list[int],
        tracks: list[Track],
        memories: list[PersonMemory],
        track_facing: FloatArray,
        t_s: float,
    ) -> tuple[npt.NDArray[np.bool_], FloatArray | None]:
        """Step 4: swap mirrored views back before anything looks at left or right (in place in
        ``batch``); a person turned over as a whole takes its track with it (``track_facing``
        updated). Returns which views were mirrored (N,) and their range-of-motion factors as
        labelled (N, 25), or None when the labels are off."""
        s = self.settings
        if not s.mirror.enabled:
            return np.zeros(len(batch.views), dtype=bool), None
        mirrored, rom, swapped = label_views(
            batch.joints,
            batch.states,
            batch.sensors,
            [(v.sensor_id, v.tracking_id) for v in batch.views],
            batch.counts,
            [t.joints if t.fused_once else None for t in tracks],
            track_facing,
            [m.labels for m in memories],
            s,
            [m.doubt for m in memories] if s.mirror.redecide or s.mirror.unbiased_facing else None,
            t_s,
        )
        for p in swapped.nonzero()[0].tolist():  # turned over: the track goes too
            self._swap_person(ids[p], relabel=False)
            track_facing[p] = facing_directions(tracks[p].joints[None])[0]
        return mirrored, rom

    def _filter(
        self,
        memories: list[PersonMemory],
        fused: FloatArray,
        alive: list[int],
        persons: int,
        t_s: float,
    ) -> dict[int, FloatArray]:
        """Step 7: each living person's (25, 3) skeleton through its filter, by row."""
        everyone = len(alive) == persons  # the usual step: the array as it is, not a gather
        filtered = filter_all(
            [memories[p].filter for p in alive],
            fused if everyone else fused[alive],
            t_s,
            self._filter_stacks,
        )
        return dict(zip(alive, filtered, strict=True))

    def _fit_bones(
        self, memories: list[PersonMemory], skeletons: dict[int, FloatArray], alive: list[int]
    ) -> None:
        """Step 8: give each filtered skeleton its person's reference bone lengths, as they are
        now that this step's observations are in (in place in ``skeletons``)."""
        if not (self.settings.bones.enforce and alive):
            return
        lengths = references_of([memories[p].bones for p in alive])
        known = np.logical_or.reduce(np.isfinite(lengths), axis=1)
        usable: list[bool] = known.tolist()
        fitted = [p for p, k in zip(alive, usable, strict=True) if k]
        if fitted:
            fit = project_bone_lengths(
                np.array([skeletons[p] for p in fitted], dtype=np.float64),
                lengths if len(fitted) == len(alive) else lengths[known],
                iterations=self.settings.bones.fit_iterations,
            )
            skeletons.update(zip(fitted, fit, strict=True))

    def _outputs(
        self,
        ids: list[int],
        alive: list[int],
        skeletons: dict[int, FloatArray],
        weighed: Weighed,
        batch: ViewBatch,
        mirrored: npt.NDArray[np.bool_],
    ) -> dict[int, FusedPerson]:
        """The living persons as published, by id: skeleton, confidence, views, carriers."""
        everyone = len(alive) == len(ids)
        flags = mirrored.tolist()
        starts = batch.starts.tolist()
        spans = [(starts[p], starts[p + 1]) for p in alive]
        persons = fused_persons(
            [ids[p] for p in alive],
            [skeletons[p] for p in alive],
            weighed.confidence if everyone else weighed.confidence[alive],
            [batch.views[lo:hi] for lo, hi in spans],
            weighed.carried if everyone else weighed.carried[alive],
            [flags[lo:hi] for lo, hi in spans],
        )
        return dict(zip([ids[p] for p in alive], persons, strict=True))

    # --- per-person state ----------------------------------------------------------------------

    def _new_memory(self) -> PersonMemory:
        s = self.settings
        bones = BoneModel(
            s.bones.window,
            s.bones.min_samples,
            s.bones.symmetric,
            s.bones.lock_samples,
        )
        if self._default_bone_lengths is not None:
            bones.set_lengths = self._default_bone_lengths.copy()
        return PersonMemory(self._new_filter(), bones)

    def _new_filter(self) -> JointFilter:
        s = self.settings
        return make_filter(
            s.smoothing.filter,
            min_cutoff_hz=s.smoothing.one_euro_min_cutoff_hz,
            beta=s.smoothing.one_euro_beta,
            d_cutoff_hz=s.smoothing.one_euro_d_cutoff_hz,
            accel_std=s.smoothing.kalman_accel_std,
            meas_std_m=s.smoothing.kalman_meas_std_m,
            predict_s=s.smoothing.kalman_predict_s,
            jerk_std=s.smoothing.kalman_ca_jerk_std,
            accel_tau_s=s.smoothing.kalman_ca_accel_tau_s,
            ca_meas_std_m=s.smoothing.kalman_ca_meas_std_m,
            ca_predict_s=s.smoothing.kalman_ca_predict_s,
            jerk_per_speed=s.smoothing.kalman_ca_jerk_per_speed,
        )

    def _check_walking_directions(
        self, ids: list[int], t_s: float, moved: tuple[FloatArray, FloatArray] | None = None
    ) -> None:
        """Swap each whole person that walks backwards for too long (mirror.walking_backwards).

        The swap takes effect from the next step: the person's skeleton and every view's
        remembered label are swapped, the filter restarts (it would otherwise sweep the limbs
        across), the online bone samples swap sides. The persons' facings come from one
        batched call (each skeleton's own, the same bits as one by one). ``moved``: the
        tracks' skeletons and velocities stacked, as ``PersonTracker.move_all`` just left them
        (None: stacked here).
        """
        s = self.settings
        tracks = [self.tracker.tracks[person_id] for person_id in ids]
        facings: list[FloatArray | None] = [None] * len(ids)
        computed: FloatArray | None = None
        self._facings = {}
        if tracks and s.mirror.walk_check_s > 0 and s.mirror.enabled:
            joints = [track.joints for track in tracks]
            stacked = moved[0] if moved is not None else np.array(joints, dtype=np.float64)
            computed = facing_directions(stacked)
            facings = list(computed)
            self._facings = {
                pid: (row, facing) for pid, row, facing in zip(ids, joints, computed, strict=True)
            }
        ahead = [False] * len(ids)  # walking forwards (or standing) for sure: nothing to time
        if computed is not None:  # one compiled call for every person
            velocities = (
                moved[1]
                if moved is not None
                else np.array([t.velocity for t in tracks], dtype=np.float64)
            )
            backwards = walking_backwards_now(velocities, computed, s.mirror.walk_min_speed_mps)
            ahead = (~backwards).tolist()
        for person_id, track, facing, forwards in zip(ids, tracks, facings, ahead, strict=True):
            memory = self.memories[person_id]
            if forwards:  # what walking_backwards gives then
                memory.backward_since_s = None
                continue
            swap, memory.backward_since_s = walking_backwards(
                track.joints, track.velocity, t_s, memory.backward_since_s, s, facing
            )
            if swap:
                self._swap_person(person_id, relabel=True)
                memory.walk_swaps += 1

    def _track_facings(self, ids: list[int], tracks: list[Track]) -> FloatArray:
        """(P, 3) each person's facing from its track's skeleton (:func:`facing_directions`,
        row by row the same bits): the walking check's at the end of the last step when no
        track has moved or turned over since (the usual case), else computed now."""
        cached = [self._facings.get(person_id) for person_id in ids]
        if all(c is not None and c[0] is t.joints for c, t in zip(cached, tracks, strict=True)):
            return np.array([c[1] for c in cached if c is not None])
        return facing_directions(np.stack([t.joints for t in tracks]))

    def _swap_person(self, person_id: int, relabel: bool) -> None:
        """Swap a whole person's sides: its track, its filter (which would otherwise sweep the
        limbs across), its bone samples, and with ``relabel`` every view's remembered label."""
        memory = self.memories[person_id]
        self.tracker.swap_sides(person_id)
        if relabel:
            memory.labels = {key: not m for key, m in memory.labels.items()}
            memory.doubt.facing = -memory.doubt.facing  # swapped sides face the other way
        memory.filter = self._new_filter()
        memory.bones.mirror()

    # --- reference bone lengths (REST: server/routes_fusion.py) ---------------------------------

    @property
    def track_count(self) -> int:
        return len(self.tracker.tracks)

    def person_ids(self) -> list[int]:
        """Ids of the persons currently published."""
        return sorted(pid for pid, t in self.tracker.tracks.items() if t.published)

    def bone_model(self, person_id: int) -> BoneModel | None:
        memory = self.memories.get(person_id)
        return None if memory is None else memory.bones

    @property
    def default_bone_lengths(self) -> FloatArray | None:
        """(24,) lengths every new person starts with as "set" (None: estimated online)."""
        return None if self._default_bone_lengths is None else self._default_bone_lengths.copy()

    def set_default_bone_lengths(self, lengths: npt.ArrayLike | None) -> None:
        """Set (or with None, clear) the lengths new persons start with; existing ones keep theirs.

        Args:
            lengths: (24,) metres in :data:`~skelfuse.protocol.skeleton.BONES` order, or None.
        """
        self._default_bone_lengths = (
            None if lengths is None else np.array(lengths, dtype=np.float64).reshape(-1)
        )

    def set_bone_lengths(self, person_id: int, lengths: FloatArray | None) -> bool:
        """Set (or with None, clear back to automatic) a person's reference lengths.

        Args:
            lengths: (24,) metres in :data:`~skelfuse.protocol.skeleton.BONES` order, or None.

        Returns:
            False if there is no such person.
        """
        memory = self.memories.get(person_id)
        if memory is None:
            return False
        memory.bones.set_lengths = None if lengths is None else np.array(lengths, dtype=float)
        return True
