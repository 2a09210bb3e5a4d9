"""What a Kinect v2 reports when it looks at the virtual performers.

The model reproduces the failure modes that make multi-sensor fusion necessary, with magnitudes
taken from published Kinect v2 evaluations and from our own measurements on public multi-view
recordings (``shared/conventions.md`` §5). Each is a parameter of :class:`KinectV2Params`:

- Field of view 70.6°×60° and range 0.5–4.5 m: joints outside are NotTracked; a body whose
  trunk is outside is not reported at all.
- Jitter: white noise with σ = ``jitter_base_m + jitter_per_m2·z²`` (grows with depth z).
- Systematic error: each joint of each tracked body drifts around the truth as a slow AR(1)
  process (σ per joint group, correlation time ``bias_tau_s``), larger at the extremities.
- Self- and mutual occlusion: a joint hidden behind a body part (capsules around trunk, head and
  limbs of every person) is reported Inferred, with a larger, slowly varying error.
- Facing bias: the tracker assumes the person faces it and turns the skeleton towards the
  sensor by ``facing_bias`` of their true yaw relative to it (measured ≈ 0.5 on NTU RGB+D).
- Facing away: past ``mirror_threshold_deg`` the body is reported as if facing the sensor, with
  left and right swapped (the classic Kinect failure), plus the facing bias on top.
- Glitches: now and then a limb jumps by 15–40 cm for a few frames while still Tracked, and a
  body is occasionally lost for a moment and comes back under a new tracking id.

The geometry (field of view, range, occlusion capsules, yaw to the sensor) is
:mod:`agent.sim.sight`, shared with the other error model (:mod:`agent.sim.tracker_model`).

Frames: input joints are in the world (+Y up, metres); output joints are in the sensor's camera
frame (+X sensor-left, +Y up, +Z forward, metres), as the SDK reports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final, TypeVar

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.sight import TRUNK, facing_angle, in_view, sight_lines, trunk_visible
from skelfuse.protocol.constants import MAX_BODIES
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, JointId, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, invert

J = JointId
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class KinectV2Params:
    """Sensor model parameters (defaults: Kinect v2 as measured; see module docstring)."""

    fov_horizontal_deg: float = 70.6
    fov_vertical_deg: float = 60.0
    min_range_m: float = 0.5
    max_range_m: float = 4.5
    fps: float = 30.0
    jitter_base_m: float = 0.002
    jitter_per_m2: float = 0.001
    bias_tau_s: float = 1.0
    bias_trunk_m: float = 0.012
    bias_limb_m: float = 0.02
    bias_extremity_m: float = 0.035
    inferred_error_m: float = 0.08
    inferred_tau_s: float = 0.5
    facing_bias: float = 0.5
    mirror_threshold_deg: float = 105.0
    mirror_hysteresis_deg: float = 10.0
    glitch_rate_hz: float = 0.1
    glitch_size_m: tuple[float, float] = (0.15, 0.40)
    glitch_frames: tuple[int, int] = (2, 8)
    dropout_rate_hz: float = 0.01
    dropout_s: tuple[float, float] = (0.2, 1.0)


_EXTREMITIES: Final = (
    J.HAND_LEFT,
    J.HAND_RIGHT,
    J.HAND_TIP_LEFT,
    J.HAND_TIP_RIGHT,
    J.THUMB_LEFT,
    J.THUMB_RIGHT,
    J.FOOT_LEFT,
    J.FOOT_RIGHT,
)
_GLITCH_CHAINS: Final = (
    (J.ELBOW_LEFT, J.WRIST_LEFT, J.HAND_LEFT, J.HAND_TIP_LEFT, J.THUMB_LEFT),
    (J.ELBOW_RIGHT, J.WRIST_RIGHT, J.HAND_RIGHT, J.HAND_TIP_RIGHT, J.THUMB_RIGHT),
    (J.KNEE_LEFT, J.ANKLE_LEFT, J.FOOT_LEFT),
    (J.KNEE_RIGHT, J.ANKLE_RIGHT, J.FOOT_RIGHT),
    (J.WRIST_LEFT, J.HAND_LEFT, J.HAND_TIP_LEFT, J.THUMB_LEFT),
    (J.WRIST_RIGHT, J.HAND_RIGHT, J.HAND_TIP_RIGHT, J.THUMB_RIGHT),
)


def _bias_scale(params: KinectV2Params) -> FloatArray:
    scale = np.full(JOINT_COUNT, params.bias_limb_m)
    scale[list(TRUNK)] = params.bias_trunk_m
    scale[list(_EXTREMITIES)] = params.bias_extremity_m
    return scale


@dataclass(slots=True)
class _TrackedBody:
    tracking_id: int
    bias: FloatArray
    inferred_error: FloatArray
    mirrored: bool = False
    glitch_frames_left: int = 0
    glitch_chain: tuple[int, ...] = ()
    glitch_offset: FloatArray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True, slots=True)
class Observation:
    """One body as the sensor reports it (sensor frame, see module docstring).

    ``person`` is the ground-truth index of the person it came from (simulation only; never sent
    on the wire), ``mirrored`` whether the sensor swapped left and right for the whole body.
    ``true_joints``, when set: (25,) the true joint each reported joint is (reported joint ``i``
    shows true joint ``true_joints[i]``; a permutation covering whole-body mirrors and swaps of
    single limbs), so ``put_right[true_joints] = joints_m`` puts every label right. None means
    "identity, or the whole-body mirror when ``mirrored``" (the Kinect model swaps nothing
    else).
    """

    tracking_id: int
    joints_m: npt.NDArray[np.float32]
    states: npt.NDArray[np.uint8]
    person: int
    mirrored: bool
    true_joints: npt.NDArray[np.intp] | None = None

    def labels_put_right(self) -> npt.NDArray[np.float32]:
        """(25, 3) ``joints_m`` with every joint under its true label (sensor frame, metres)."""
        return labels_put_right(self.joints_m, self.mirrored, self.true_joints)


_Scalar = TypeVar("_Scalar", bound=np.generic)


def labels_put_right(
    joints: npt.NDArray[_Scalar], mirrored: bool, true_joints: npt.NDArray[np.intp] | None
) -> npt.NDArray[_Scalar]:
    """(25, 3) reported ``joints`` moved under their true labels (see :class:`Observation`)."""
    if true_joints is not None:
        out = np.empty_like(joints)
        out[true_joints] = joints
        return out
    if mirrored:
        return joints[list(MIRROR_PERMUTATION)]
    return joints.copy()


class SimulatedKinect:
    """A Kinect v2 standing at ``T_world_from_sensor``; call :meth:`observe` once per frame."""

    def __init__(
        self,
        T_world_from_sensor: Matrix4,
        params: KinectV2Params | None = None,
        seed: int = 0,
    ) -> None:
        self.params = params or KinectV2Params()
        self.T_world_from_sensor = np.asarray(T_world_from_sensor, dtype=np.float64)
        self._T_sensor_from_world = invert(self.T_world_from_sensor)
        self._rng = np.random.default_rng(seed)
        self._bodies: dict[int, _TrackedBody] = {}
        self._dropout_until: dict[int, float] = {}
        self._last_t: float | None = None
        self._bias_scale = _bias_scale(self.params)

    @property
    def position_m(self) -> FloatArray:
        return self.T_world_from_sensor[:3, 3].copy()

    def floor_plane(self) -> tuple[float, float, float, float]:
        """The floor (world y = 0) as the SDK's ``FloorClipPlane`` in the sensor frame."""
        normal = self.T_world_from_sensor[:3, :3].T @ np.array([0.0, 1.0, 0.0])
        height = float(self.T_world_from_sensor[1, 3])
        return (float(normal[0]), float(normal[1]), float(normal[2]), height)

    def observe(self, persons_world: FloatArray, t_s: float) -> list[Observation]:
        """What the sensor reports at ``t_s`` for people at ``persons_world``.

        Args:
            persons_world: (P, 25, 3) true joints, metres, world frame.
            t_s: capture time in seconds (drives the temporal error processes).
        """
        p = self.params
        dt = 1.0 / p.fps if self._last_t is None else min(max(t_s - self._last_t, 0.0), 1.0)
        self._last_t = t_s
        persons_world = np.asarray(persons_world, dtype=np.float64)
        persons_sensor = apply(self._T_sensor_from_world, persons_world)
        seen = in_view(
            persons_sensor, p.fov_horizontal_deg, p.fov_vertical_deg, p.min_range_m, p.max_range_m
        )
        occluded, _ = sight_lines(persons_sensor)
        observations: list[Observation] = []
        for person in range(persons_world.shape[0]):
            visible = trunk_visible(seen[person])
            if not visible or self._dropped_out(person, t_s, dt):
                self._bodies.pop(person, None)
                continue
            if len(observations) == MAX_BODIES:
                break
            body = self._bodies.get(person)
            if body is None:
                body = self._new_body()
                self._bodies[person] = body
            observations.append(
                self._report(
                    person, body, persons_world[person], seen[person], occluded[person], dt
                )
            )
        return observations

    # --- internals ------------------------------------------------------------------------

    def _new_body(self) -> _TrackedBody:
        p = self.params
        return _TrackedBody(
            tracking_id=int(self._rng.integers(1, 2**63, dtype=np.int64)) * 2 + 1,
            bias=self._rng.normal(size=(JOINT_COUNT, 3)) * self._bias_scale[:, None],
            inferred_error=self._rng.normal(size=(JOINT_COUNT, 3)) * p.inferred_error_m,
        )

    def _dropped_out(self, person: int, t_s: float, dt: float) -> bool:
        p = self.params
        until = self._dropout_until.get(person)
        if until is not None and t_s < until:
            return True
        if self._rng.random() < p.dropout_rate_hz * dt:
            self._dropout_until[person] = t_s + self._rng.uniform(*p.dropout_s)
            return True
        return False

    def _report(
        self,
        person: int,
        body: _TrackedBody,
        joints_world: FloatArray,
        joints_in_view: npt.NDArray[np.bool_],
        occluded: npt.NDArray[np.bool_],
        dt: float,
    ) -> Observation:
        p = self.params
        rng = self._rng
        angle = facing_angle(joints_world, self.position_m)
        threshold = math.radians(
            p.mirror_threshold_deg - (p.mirror_hysteresis_deg if body.mirrored else 0.0)
        )
        body.mirrored = abs(angle) > threshold
        reported = joints_world.copy()
        if body.mirrored:
            # The tracker fits a front-facing body to the person's back: labels swap sides.
            reported = reported[list(MIRROR_PERMUTATION)]
            angle -= math.copysign(math.pi, angle)  # the apparent front is the true back
        # Turn the skeleton towards the sensor by a fraction of its yaw relative to it.
        turn = p.facing_bias * max(-math.pi / 2, min(math.pi / 2, angle))
        pivot = reported[J.SPINE_BASE].copy()
        c, s = math.cos(turn), math.sin(turn)
        rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        reported = (reported - pivot) @ rot.T + pivot

        # Temporal error processes (AR(1) keeps their stationary σ whatever the frame rate).
        decay = math.exp(-dt / p.bias_tau_s)
        body.bias = body.bias * decay + rng.normal(size=(JOINT_COUNT, 3)) * (
            self._bias_scale[:, None] * math.sqrt(1 - decay**2)
        )
        decay_inf = math.exp(-dt / p.inferred_tau_s)
        body.inferred_error = body.inferred_error * decay_inf + rng.normal(
            size=(JOINT_COUNT, 3)
        ) * (p.inferred_error_m * math.sqrt(1 - decay_inf**2))

        sensor_points = apply(self._T_sensor_from_world, reported)
        # Mirrored labels move the in-view/occlusion flags with the joints they describe.
        order = list(MIRROR_PERMUTATION) if body.mirrored else list(range(JOINT_COUNT))
        seen = joints_in_view[order]
        hidden = occluded[order]
        depth = np.maximum(sensor_points[:, 2], 0.0)
        jitter = (
            rng.normal(size=(JOINT_COUNT, 3))
            * (p.jitter_base_m + p.jitter_per_m2 * depth**2)[:, None]
        )
        sensor_points += body.bias + jitter
        sensor_points[hidden] += body.inferred_error[hidden]

        self._advance_glitch(body, dt)
        if body.glitch_frames_left > 0:
            sensor_points[list(body.glitch_chain)] += body.glitch_offset

        states = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)
        states[hidden] = TrackingState.INFERRED
        states[~seen] = TrackingState.NOT_TRACKED
        joints = sensor_points.astype(np.float32)
        joints[~seen] = np.nan
        return Observation(
            tracking_id=body.tracking_id,
            joints_m=joints,
            states=states,
            person=person,
            mirrored=body.mirrored,
        )

    def _advance_glitch(self, body: _TrackedBody, dt: float) -> None:
        p = self.params
        if body.glitch_frames_left > 0:
            body.glitch_frames_left -= 1
            return
        if self._rng.random() < p.glitch_rate_hz * dt:
            chain = _GLITCH_CHAINS[int(self._rng.integers(len(_GLITCH_CHAINS)))]
            direction = self._rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            body.glitch_chain = tuple(int(j) for j in chain)
            body.glitch_offset = direction * self._rng.uniform(*p.glitch_size_m)
            body.glitch_frames_left = int(
                self._rng.integers(p.glitch_frames[0], p.glitch_frames[1] + 1)
            )
