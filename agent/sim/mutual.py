"""Mutual capture: people wearing head-mounted depth sensors, each capturing the others.

Report B's setting (``shared/papers.md``, B): every wearer's sensor (:class:`HeadRig`) moves
with their head; its tracker reports the others in the sensor's own frame, and the frame is
tagged with the sensor's pose as the headset's tracker knows it (:class:`PoseErrors`: noise,
and the pose of a slightly wrong instant). The Kinect v2 model
(:mod:`agent.sim.kinect_model`: field of view, occlusion, noise, mirrored guesses, glitches)
is moved to the sensor's true pose before every frame; a sensor never sees its own wearer.

Each wearer looks horizontally at the others (towards the mean of their mid-spines) and turns
their head by the rig's schedule on top. Everything is a deterministic function of time and the
seed, so separate agent processes simulating one scene agree on the people (as in
:mod:`agent.sim.performer`).

Frames: world +Y up, metres; the tracking space of every pose is the world here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.head_mounted import HeadRig, PoseErrors, noisy_pose
from skelfuse.agent.sim.kinect_model import KinectV2Params, Observation, SimulatedKinect
from skelfuse.agent.sim.performer import Performer
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import Matrix4, invert

J = JointId


class MovingKinect(SimulatedKinect):
    """A :class:`SimulatedKinect` that can be moved between frames (its error processes go on)."""

    def move_to(self, T_world_from_sensor: Matrix4) -> None:
        """Put the sensor at ``T_world_from_sensor`` (4×4, metres) for the next frames."""
        self.T_world_from_sensor = np.asarray(T_world_from_sensor, dtype=np.float64)
        self._T_sensor_from_world = invert(self.T_world_from_sensor)


@dataclass(frozen=True, slots=True)
class WearerFrame:
    """One frame of one wearer's sensor.

    bodies: the others as the sensor reports them, sensor frame (``person`` is the index in the
    scene, ground truth for benchmarks only); pose: the ``T_space_from_sensor`` the headset
    attaches (with :class:`PoseErrors`); true_pose: the true ``T_world_from_sensor`` at
    ``t_s``; floor: the floor plane in the sensor frame (the SDK's ``FloorClipPlane``).
    """

    wearer: int
    t_s: float
    bodies: tuple[Observation, ...]
    pose: SensorPose
    true_pose: Matrix4
    floor: tuple[float, float, float, float]


class MutualCapture:
    """Wearers of head-mounted sensors in a scene of people (see module docstring).

    Args:
        performer: everyone in the scene, the ground truth (P people).
        rigs: one :class:`HeadRig` per wearer; wearer i is person i of ``performer``.
        errors: what is wrong with the poses the headsets report.
        params: the sensor model (default: Kinect v2).
        seed: noise seed; wearer i's sensor uses ``seed + 1000·i``, its pose noise another.

    Raises:
        ValueError: more rigs than people, or fewer than one.
    """

    def __init__(
        self,
        performer: Performer,
        rigs: Sequence[HeadRig],
        *,
        errors: PoseErrors | None = None,
        params: KinectV2Params | None = None,
        seed: int = 0,
    ) -> None:
        if not 1 <= len(rigs) <= performer.person_count:
            raise ValueError(f"{len(rigs)} wearers for {performer.person_count} people")
        self.performer = performer
        self.rigs = tuple(rigs)
        self.errors = errors or PoseErrors()
        self._params = params
        self._seed = seed
        self._kinects: dict[int, MovingKinect] = {}
        self._pose_rngs: dict[int, np.random.Generator] = {}

    @property
    def wearer_count(self) -> int:
        return len(self.rigs)

    def truth(self, t_s: float) -> npt.NDArray[np.float64]:
        """(P, 25, 3) everyone's true joints at ``t_s``, metres, world frame."""
        return self.performer.joints_at(t_s)

    def sensor_pose(
        self, wearer: int, t_s: float, persons: npt.NDArray[np.float64] | None = None
    ) -> Matrix4:
        """Wearer ``wearer``'s true ``T_world_from_sensor`` (4×4) at ``t_s``.

        ``persons``: the scene's joints at ``t_s`` when the caller has them already.
        """
        people = self.truth(t_s) if persons is None else persons
        neck = people[wearer, J.NECK]
        others = [p for p in range(people.shape[0]) if p != wearer]
        if others:
            target = people[others, J.SPINE_MID].mean(axis=0) - neck
            heading = math.atan2(float(target[0]), float(target[2]))
        else:
            heading = 0.0
        return self.rigs[wearer].sensor_pose(neck, heading, t_s)

    def frame(self, wearer: int, t_s: float) -> WearerFrame:
        """What wearer ``wearer``'s sensor reports for the frame captured at ``t_s``.

        Frames of one wearer must come in time order (the sensor's error processes run on).
        """
        persons = self.truth(t_s)
        true_pose = self.sensor_pose(wearer, t_s, persons)
        kinect = self._kinect(wearer)
        kinect.move_to(true_pose)
        others = [p for p in range(persons.shape[0]) if p != wearer]
        seen = kinect.observe(persons[others], t_s)
        bodies = tuple(replace(o, person=others[o.person]) for o in seen)
        mismatch_s = self.errors.mismatch_ms * 1e-3
        posed = true_pose if mismatch_s == 0 else self.sensor_pose(wearer, t_s + mismatch_s)
        pose = noisy_pose(posed, self.errors, self._pose_rng(wearer))
        return WearerFrame(wearer, t_s, bodies, pose, true_pose, kinect.floor_plane())

    def _kinect(self, wearer: int) -> MovingKinect:
        kinect = self._kinects.get(wearer)
        if kinect is None:
            kinect = MovingKinect(np.eye(4), self._params, seed=self._seed + 1000 * wearer)
            self._kinects[wearer] = kinect
        return kinect

    def _pose_rng(self, wearer: int) -> np.random.Generator:
        rng = self._pose_rngs.get(wearer)
        if rng is None:
            rng = np.random.default_rng(self._seed + 1000 * wearer + 500)
            self._pose_rngs[wearer] = rng
        return rng
