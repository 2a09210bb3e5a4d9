"""A second sensor error model: a depth body tracker that fits a body model to the depth image.

Built independently of :mod:`agent.sim.kinect_model` so that fusion, whose confidence was tuned
on the Kinect model, can be judged on errors of another structure (not only other magnitudes).
It shares only the geometry of what can be seen (:mod:`agent.sim.sight`: field of view, range,
occlusion capsules, yaw to the sensor). Each effect is a parameter of :class:`DepthTrackerParams`:

- Body fit: the fitted body's size is off by a factor drawn per track (σ ``body_scale_sd``),
  about the pelvis.
- Lean towards the sensor: the fit turns the body towards the sensor by
  ``lean_max_deg · sin ψ·|sin ψ| / sin² ψ_sat`` with ψ the apparent yaw clipped at
  ``lean_saturation_deg``: little lean near frontal, growing quadratically, saturating; larger
  when the sensor is on the person's left (× (1 + ``lean_asymmetry``)) than on their right
  (× (1 − ``lean_asymmetry``)).
- Side views, depth: the fit sits behind the visible surface: each joint is pushed along the
  sensor's ray, away from it, by ``side_depth_bias_m · sin² yaw`` (0 frontal, full side-on),
  limbs of the far side × (1 + ``far_side_gain``).
- Side views, labels: seen side-on (|sin yaw| ≥ ``limb_swap_min_side``) a single arm or leg
  pair is now and then fitted the wrong way round (its left and right joints swapped, not the
  whole body) for ``limb_swap_frames`` frames, at ``limb_swap_rate_hz``; never in frontal or
  back views.
- Occlusion: a hidden joint is Inferred and pulled ``occlusion_pull`` of the way from where it
  is fitted towards the near surface of what hides it (towards the sensor, along its ray), plus
  white noise ``occlusion_noise_m``.
- Depth noise: along the ray, σ = ``depth_noise_per_m2 · d²`` (d: distance to the sensor),
  correlated in time (AR(1), ``depth_noise_tau_s``); across the ray, small white noise
  σ = ``across_noise_rad · d``.
- Seen from behind: the front-facing fit is mirrored (the whole body left/right swapped) with a
  probability that rises smoothly around ``mirror_threshold_deg`` (logistic, width
  ``mirror_width_deg``); the decision is a two-state process switching at up to
  ``mirror_switch_hz``, so near the threshold it flickers for a few frames at a time, and deep
  in a back view it holds.
- Glitches: at ``glitch_rate_hz`` a whole chain (an arm from the shoulder, a leg from the hip,
  or neck and head) jumps by a heavy-tailed amount (``glitch_scale_m`` × |Student t with
  ``glitch_dof`` degrees of freedom|, capped at ``glitch_max_m``) for ``glitch_frames`` frames,
  still Tracked.
- Track loss: at ``dropout_rate_hz``, times (1 + 10 × the share of the body hidden); the body is
  re-acquired after ``dropout_s`` under the next tracking id (ids count up from 1 per sensor).

Every :class:`~agent.sim.kinect_model.Observation` carries ``true_joints``: the true joint each
reported joint is (whole-body mirror and single-limb swaps composed), so benchmarks can put
labels right; ``mirrored`` still means "the whole body was reported left/right swapped".

Frames: input joints are in the world (+Y up, metres); output joints are in the sensor's camera
frame (+X sensor-left, +Y up, +Z forward, metres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.kinect_model import Observation
from skelfuse.agent.sim.sight import facing_angle, in_view, sight_lines, trunk_visible
from skelfuse.protocol.constants import MAX_BODIES
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION, JointId, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, invert

J = JointId
FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class DepthTrackerParams:
    """The depth body tracker's error model (see module docstring for what each does)."""

    fov_horizontal_deg: float = 70.6
    fov_vertical_deg: float = 60.0
    min_range_m: float = 0.5
    max_range_m: float = 4.5
    fps: float = 30.0
    depth_noise_per_m2: float = 0.003
    depth_noise_tau_s: float = 0.3
    across_noise_rad: float = 0.0015
    body_scale_sd: float = 0.03
    lean_max_deg: float = 30.0
    lean_saturation_deg: float = 65.0
    lean_asymmetry: float = 0.3
    side_depth_bias_m: float = 0.04
    far_side_gain: float = 1.5
    limb_swap_min_side: float = 0.8
    limb_swap_rate_hz: float = 0.5
    limb_swap_frames: tuple[int, int] = (6, 20)
    occlusion_pull: float = 0.6
    occlusion_noise_m: float = 0.02
    mirror_threshold_deg: float = 115.0
    mirror_width_deg: float = 8.0
    mirror_switch_hz: float = 4.0
    glitch_rate_hz: float = 0.15
    glitch_scale_m: float = 0.06
    glitch_dof: float = 2.5
    glitch_max_m: float = 1.0
    glitch_frames: tuple[int, int] = (1, 6)
    dropout_rate_hz: float = 0.02
    dropout_s: tuple[float, float] = (0.3, 1.5)


_LEFT_ARM: Final = (J.ELBOW_LEFT, J.WRIST_LEFT, J.HAND_LEFT, J.HAND_TIP_LEFT, J.THUMB_LEFT)
_LEFT_LEG: Final = (J.KNEE_LEFT, J.ANKLE_LEFT, J.FOOT_LEFT)
SWAPPABLE_LIMBS: Final[tuple[tuple[int, ...], ...]] = (
    tuple(int(j) for j in _LEFT_ARM),
    tuple(int(j) for j in _LEFT_LEG),
)
"""The left joints of each limb a side view may fit the wrong way round (with their mirrors)."""
_CHAINS: Final = (
    (J.SHOULDER_LEFT, *_LEFT_ARM),
    (J.SHOULDER_RIGHT, J.ELBOW_RIGHT, J.WRIST_RIGHT, J.HAND_RIGHT, J.HAND_TIP_RIGHT,
     J.THUMB_RIGHT),
    (J.HIP_LEFT, *_LEFT_LEG),
    (J.HIP_RIGHT, J.KNEE_RIGHT, J.ANKLE_RIGHT, J.FOOT_RIGHT),
    (J.NECK, J.HEAD),
)  # fmt: skip
_MIRROR: Final = np.array(MIRROR_PERMUTATION, dtype=np.intp)
_SIDE: Final = np.zeros(JOINT_COUNT)  # +1 left-side joints, −1 right-side, 0 on the midline
for _j in range(JOINT_COUNT):
    if _MIRROR[_j] != _j:
        _SIDE[_j] = 1.0 if "LEFT" in JointId(_j).name else -1.0


def limb_swap(left_joints: tuple[int, ...]) -> IndexArray:
    """(25,) the permutation swapping one limb's left joints with their right counterparts."""
    order = np.arange(JOINT_COUNT, dtype=np.intp)
    left = np.array(left_joints, dtype=np.intp)
    order[left], order[_MIRROR[left]] = _MIRROR[left], left
    return order


def mirror_probability(abs_yaw_rad: float, params: DepthTrackerParams) -> float:
    """The chance that the fit is mirrored at this |yaw| (logistic around the threshold)."""
    x = (math.degrees(abs_yaw_rad) - params.mirror_threshold_deg) / params.mirror_width_deg
    return 1.0 / (1.0 + math.exp(-max(-50.0, min(50.0, x))))


def lean_turn(apparent_yaw_rad: float, params: DepthTrackerParams) -> float:
    """Turn (radians, towards the sensor: it reduces the yaw) the fit adds at this yaw."""
    saturation = math.radians(params.lean_saturation_deg)
    yaw = max(-saturation, min(saturation, apparent_yaw_rad))
    shape = math.sin(yaw) * abs(math.sin(yaw)) / math.sin(saturation) ** 2
    side = 1.0 + params.lean_asymmetry * (1.0 if yaw > 0 else -1.0)
    return math.radians(params.lean_max_deg) * shape * side


@dataclass(slots=True)
class _Track:
    tracking_id: int
    scale: float
    depth_noise: FloatArray  # (25,) unit AR(1) state along each reported joint's ray
    mirrored: bool = False
    swap: IndexArray | None = None
    swap_frames_left: int = 0
    glitch_frames_left: int = 0
    glitch_chain: tuple[int, ...] = ()
    glitch_offset: FloatArray = field(default_factory=lambda: np.zeros(3))


class SimulatedDepthTracker:
    """A depth body tracker at ``T_world_from_sensor``; call :meth:`observe` once per frame.

    The same interface as :class:`~agent.sim.kinect_model.SimulatedKinect`.
    """

    def __init__(
        self,
        T_world_from_sensor: Matrix4,
        params: DepthTrackerParams | None = None,
        seed: int = 0,
    ) -> None:
        self.params = params or DepthTrackerParams()
        self.T_world_from_sensor = np.asarray(T_world_from_sensor, dtype=np.float64)
        self._T_sensor_from_world = invert(self.T_world_from_sensor)
        self._rng = np.random.default_rng(seed)
        self._tracks: dict[int, _Track] = {}
        self._lost_until: dict[int, float] = {}
        self._next_id = 1
        self._last_t: float | None = None

    @property
    def position_m(self) -> FloatArray:
        return self.T_world_from_sensor[:3, 3].copy()

    def floor_plane(self) -> tuple[float, float, float, float]:
        """The floor (world y = 0) as a ``FloorClipPlane`` in the sensor frame."""
        normal = self.T_world_from_sensor[:3, :3].T @ np.array([0.0, 1.0, 0.0])
        height = float(self.T_world_from_sensor[1, 3])
        return (float(normal[0]), float(normal[1]), float(normal[2]), height)

    def observe(self, persons_world: FloatArray, t_s: float) -> list[Observation]:
        """What the tracker reports at ``t_s`` for people at ``persons_world``.

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
        hidden, entry_m = sight_lines(persons_sensor)
        observations: list[Observation] = []
        for person in range(persons_world.shape[0]):
            lost = self._lost(person, t_s, dt, float(hidden[person].mean()))
            if not trunk_visible(seen[person]) or lost:
                self._tracks.pop(person, None)
                continue
            if len(observations) == MAX_BODIES:
                break
            track = self._tracks.get(person)
            if track is None:
                track = self._new_track(persons_world[person])
                self._tracks[person] = track
            sight = (persons_sensor[person], seen[person], hidden[person], entry_m[person])
            observations.append(self._report(person, track, persons_world[person], sight, dt))
        return observations

    # --- internals ------------------------------------------------------------------------

    def _new_track(self, joints_world: FloatArray) -> _Track:
        p, rng = self.params, self._rng
        track = _Track(
            tracking_id=self._next_id,
            scale=1.0 + float(rng.normal()) * p.body_scale_sd,
            depth_noise=rng.normal(size=JOINT_COUNT),
        )
        self._next_id += 1
        yaw = abs(facing_angle(joints_world, self.position_m))
        track.mirrored = bool(rng.random() < mirror_probability(yaw, p))
        return track

    def _lost(self, person: int, t_s: float, dt: float, hidden_share: float) -> bool:
        p = self.params
        until = self._lost_until.get(person)
        if until is not None and t_s < until:
            return True
        if self._rng.random() < p.dropout_rate_hz * (1.0 + 10.0 * hidden_share) * dt:
            self._lost_until[person] = t_s + self._rng.uniform(*p.dropout_s)
            return True
        return False

    def _advance_labels(self, track: _Track, yaw: float, dt: float) -> IndexArray:
        """Step the mirror and limb-swap processes; (25,) the true joint of each reported one."""
        p, rng = self.params, self._rng
        back = mirror_probability(abs(yaw), p)
        toward = (1.0 - back) if track.mirrored else back
        if rng.random() < 1.0 - math.exp(-p.mirror_switch_hz * dt * toward):
            track.mirrored = not track.mirrored
        if track.swap_frames_left > 0:
            track.swap_frames_left -= 1
            if track.swap_frames_left == 0:
                track.swap = None
        elif abs(math.sin(yaw)) >= p.limb_swap_min_side and rng.random() < (
            p.limb_swap_rate_hz * dt
        ):
            track.swap = limb_swap(SWAPPABLE_LIMBS[int(rng.integers(len(SWAPPABLE_LIMBS)))])
            track.swap_frames_left = int(rng.integers(p.limb_swap_frames[0],
                                                      p.limb_swap_frames[1] + 1))  # fmt: skip
        order = _MIRROR.copy() if track.mirrored else np.arange(JOINT_COUNT, dtype=np.intp)
        return order if track.swap is None else order[track.swap]

    def _fitted_body(
        self, track: _Track, joints_world: FloatArray, yaw: float, order: IndexArray
    ) -> FloatArray:
        """(25, 3) world: the true joints under the fit's labels (``order``), scaled, leant."""
        reported = joints_world[order]
        apparent = yaw - math.copysign(math.pi, yaw) if track.mirrored else yaw
        turn = lean_turn(apparent, self.params)
        pivot = reported[J.SPINE_BASE].copy()
        c, s = math.cos(turn), math.sin(turn)
        rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        fitted: FloatArray = track.scale * (reported - pivot) @ rot.T + pivot
        return fitted

    def _report(
        self,
        person: int,
        track: _Track,
        joints_world: FloatArray,
        sight: tuple[FloatArray, BoolArray, BoolArray, FloatArray],
        dt: float,
    ) -> Observation:
        true_sensor, seen_true, hidden_true, entry_true = sight
        yaw = facing_angle(joints_world, self.position_m)
        order = self._advance_labels(track, yaw, dt)
        fitted = self._fitted_body(track, joints_world, yaw, order)
        points = apply(self._T_sensor_from_world, fitted)
        points = self._side_depth_bias(points, true_sensor, yaw, order)
        hidden = hidden_true[order]
        points = self._occlusion_pull(points, true_sensor[order], entry_true[order], hidden)
        points = self._noise(track, points, dt)
        self._advance_glitch(track, dt)
        if track.glitch_frames_left > 0:
            points[list(track.glitch_chain)] += track.glitch_offset
        seen = seen_true[order]
        states = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)
        states[hidden] = TrackingState.INFERRED
        states[~seen] = TrackingState.NOT_TRACKED
        joints = points.astype(np.float32)
        joints[~seen] = np.nan
        return Observation(track.tracking_id, joints, states, person, track.mirrored, order)

    def _side_depth_bias(
        self, points: FloatArray, true_sensor: FloatArray, yaw: float, order: IndexArray
    ) -> FloatArray:
        """Push each joint along its ray, away from the sensor, more side-on and far side."""
        p = self.params
        distance = np.linalg.norm(true_sensor, axis=1)
        left_far = (distance[[J.SHOULDER_LEFT, J.HIP_LEFT]].sum()
                    > distance[[J.SHOULDER_RIGHT, J.HIP_RIGHT]].sum())  # fmt: skip
        far_side = 1.0 if left_far else -1.0
        far = _SIDE[order] == far_side
        push = p.side_depth_bias_m * math.sin(yaw) ** 2 * (1.0 + p.far_side_gain * far)
        rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-9)
        out: FloatArray = points + rays * push[:, None]
        return out

    def _occlusion_pull(
        self, points: FloatArray, true_points: FloatArray, entry_m: FloatArray, hidden: BoolArray
    ) -> FloatArray:
        """Hidden joints pulled towards the near surface of what hides them (sensor frame)."""
        p = self.params
        out = points.copy()
        if not hidden.any():
            return out
        rays = true_points[hidden] / np.linalg.norm(true_points[hidden], axis=1, keepdims=True)
        surface = rays * entry_m[hidden][:, None]
        noise = self._rng.normal(size=surface.shape) * p.occlusion_noise_m
        out[hidden] += p.occlusion_pull * (surface - out[hidden]) + noise
        return out

    def _noise(self, track: _Track, points: FloatArray, dt: float) -> FloatArray:
        """AR(1) depth noise along the ray (σ ∝ d²), white noise across it."""
        p, rng = self.params, self._rng
        decay = math.exp(-dt / p.depth_noise_tau_s)
        track.depth_noise = track.depth_noise * decay + rng.normal(size=JOINT_COUNT) * math.sqrt(
            1 - decay**2
        )
        distance = np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-9)
        rays = points / distance
        across = rng.normal(size=points.shape) * p.across_noise_rad * distance
        across -= np.sum(across * rays, axis=1, keepdims=True) * rays
        along = track.depth_noise[:, None] * p.depth_noise_per_m2 * distance**2
        out: FloatArray = points + rays * along + across
        return out

    def _advance_glitch(self, track: _Track, dt: float) -> None:
        p, rng = self.params, self._rng
        if track.glitch_frames_left > 0:
            track.glitch_frames_left -= 1
            return
        if rng.random() < p.glitch_rate_hz * dt:
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            size = min(p.glitch_scale_m * abs(float(rng.standard_t(p.glitch_dof))), p.glitch_max_m)
            track.glitch_chain = tuple(int(j) for j in _CHAINS[int(rng.integers(len(_CHAINS)))])
            track.glitch_offset = direction * size
            track.glitch_frames_left = int(rng.integers(p.glitch_frames[0],
                                                        p.glitch_frames[1] + 1))  # fmt: skip
