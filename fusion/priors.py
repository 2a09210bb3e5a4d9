"""What fusion assumes about each kind of sensor: one :class:`SensorPrior` per ``sensor_type``.

The sensor type is what an agent announces in its hello (``protocol.wire.SENSOR_TYPES``) and
:class:`fusion.sensors.SensorState` keeps; :func:`fusion.world_views.views_at` copies it onto
each :class:`fusion.views.View`. A prior is where fusion *starts*: each sensor's own error is
learned from the rig (fusion/rig_errors.py), from its type's :func:`prior_variances`, and the
prior's other fields (state table, fixed bone lengths, depth noise along the ray) shape the
body terms and the weighted mean. The table and what each value rests on: docs/fusion.md §7,
"Priors per sensor type".

What is measured and what is not: the Kinect v2 values are the simulator's (which models a
Kinect v2 from published evaluations); fusion's code never reads the simulator, only these
numbers. No Azure Kinect or Femto was available: their entries rest on the SDK's
documentation and on public multi-view recordings (``shared/conventions.md`` §1.2, §1.6, §5),
not on a benchmark. ``rgb`` (one ordinary camera through MediaPipe Pose,
agent/sources/mono.py) rests on the four-camera clip's figures.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.settings import FusionSettings
from skelfuse.protocol.skeleton import JointId

_log = logging.getLogger(__name__)
J = JointId


@dataclass(frozen=True, slots=True)
class SensorPrior:
    """What fusion assumes about one kind of sensor before the rig shows otherwise.

    The variances (``error_m`` and the ratios) are where learning starts
    (fusion/rig_errors.py): a sensor's own views replace them within about half a minute of
    someone moving in front of it.

    error_m: 3-D RMS error (metres) of a Tracked trunk, limb and extremity joint seen from in
        front and near (:data:`JOINT_CLASSES`).
    side_ratio, back_ratio: the variance of a view from the person's side, from behind
        (labels already put right), over that from in front.
    far_ratio: the variance of a view of a person farther than ``learning.far_m`` over that of
        a nearer one.
    state_weights: weight of a NotTracked / Inferred / Tracked joint (``None``: the settings');
        an Inferred joint's variance starts at Tracked / Inferred times a Tracked one's, and
        a state of weight 0 never counts. For Azure Kinect Body Tracking (and Femto through it)
        the agent maps confidence NONE → NotTracked, LOW → Inferred, MEDIUM and HIGH → Tracked
        (agent/sources/azure_kinect.py).
    may_mirror: whether the sensor can report a person seen from behind with left and right
        swapped. Informational for now: the mirror step (fusion/mirror.py) checks every view.
    rom_scale: multiplies ``FusionSettings.weights.rom_scale_deg`` for this sensor's views (> 1: its
        out-of-range angles are doubted less, e.g. a body model that already limits them).
    fixed_bone_lengths: the sensor fits a body model whose bone lengths are fixed per person,
        so a length that differs from the person's reference is a systematic offset of that
        model, not noise: the bone-length term leaves such views alone (factor 1).
    depth_noise_ratio: the noise along the sensor's viewing ray relative to the noise across
        it (1: the same in every direction). A camera that guesses depth from the body's
        apparent size has > 1: its variance along the ray from the sensor to the joint is
        ``ratio²`` times that across it, and the weighted mean weights its joints per axis
        (fusion/view_factors.py), so another view's depth wins where there is one.
    """

    name: str
    error_m: tuple[float, float, float] = (0.021, 0.035, 0.06)
    side_ratio: float = 4.0
    back_ratio: float = 2.0
    far_ratio: float = 1.5
    state_weights: tuple[float, float, float] | None = None
    may_mirror: bool = True
    rom_scale: float = 1.0
    fixed_bone_lengths: bool = False
    depth_noise_ratio: float = 1.0

    def table(self, settings: FusionSettings) -> tuple[float, float, float]:
        """The state weights in force: this prior's, else the settings'."""
        return settings.weights.state_weights if self.state_weights is None else self.state_weights


KINECT_V2: Final = SensorPrior("kinect_v2")
"""Kinect v2, from the simulator's model of it (agent/sim/kinect_model.py, whose magnitudes come
from published evaluations and conventions.md §5): ``error_m`` is √3 × its per-axis systematic
error of trunk, limb and extremity joints (12, 20, 35 mm); a side view's variance 4× (the
tracker leans the skeleton towards itself by about half the person's yaw, conventions.md §5,
which moves a striding ankle or a swung hand by 10–15 cm side-on); from behind 2× (a fitted
front view of a back); far 1.5× (jitter grows with the square of depth)."""

AZURE_BODY_TRACKING: Final = SensorPrior(
    "azure_kinect",
    # conventions.md §5: two synchronised Azure Kinects agree to 12-23 mm on the torso after a
    # rigid fit, i.e. about 9-16 mm per view; limbs and extremities are not measured here, so
    # they keep Kinect v2's proportions to the trunk.
    error_m=(0.015, 0.025, 0.043),
    # Azure fits a body model to the whole depth image rather than leaning a front view, so a
    # side view is taken to be less bad than a Kinect v2's; not measured here.
    side_ratio=3.0,
    # Its tracker flips front/back for some people and outfits (Azure-Kinect-Sensor-SDK issues
    # #575, #1330).
    back_ratio=2.0,
    far_ratio=1.5,
    # conventions.md §1.6 maps LOW like Kinect v2's Inferred and MEDIUM/HIGH like Tracked; no
    # measurement here says an Azure LOW joint is better or worse than a v2 Inferred one.
    state_weights=(0.0, 0.3, 0.7),
    may_mirror=True,
    rom_scale=1.0,
    # conventions.md §5: bone lengths vary 2-8 mm per track on two Azure Kinects (up to 69 mm on
    # Kinect v2): a fixed-length body model.
    fixed_bone_lengths=True,
)
"""Azure Kinect Body Tracking (k4abt 1.x): Azure Kinect DK and Orbbec Femto via the K4A wrapper.
No Azure Kinect or Femto was available: the numbers rest on public recordings and the SDK's
documentation, not on a benchmark."""

RGB_MONO: Final = SensorPrior(
    "rgb",
    # The four-camera clip: MediaPipe's 3-D shape is 80-90 mm off after Procrustes alignment,
    # split by joint class in Kinect v2's proportions.
    error_m=(0.055, 0.085, 0.13),
    # MediaPipe regresses the body from the image whichever way it faces; a side view hides the
    # far limbs (not measured per side here).
    side_ratio=2.0,
    back_ratio=2.0,
    # A farther person is fewer pixels; the clip has one distance, so this is a guess.
    far_ratio=1.5,
    # Visibility predicts MediaPipe's error poorly (23 % of joints at visibility >= 0.95 were
    # more than 0.2 torso off in 2-D on the clip), so Inferred is not far below Tracked.
    state_weights=(0.0, 0.3, 0.5),
    # Along the ray the body's distance comes from its apparent size (PnP, geometry/pnp.py):
    # 131-317 mm absolute against 80-90 mm aligned on the clip: about 3 times the noise across.
    depth_noise_ratio=3.0,
    # Seen from behind MediaPipe can swap sides like a Kinect: the mirror step checks it.
    may_mirror=True,
    rom_scale=1.0,
    # BlazePose regresses points, not a fixed-length body model.
    fixed_bone_lengths=False,
)
"""One ordinary camera through MediaPipe Pose (``sensor_type`` ``rgb``, agent/sources/mono.py).
The figures are measurements on the four-camera clip (one person, one scene); the split of
the noise between across and along the ray is an estimate from them, not a fit."""

PRIORS: Final[Mapping[str, SensorPrior]] = MappingProxyType(
    {
        "kinect_v2": KINECT_V2,
        "sim": SensorPrior("sim"),  # the simulator models a Kinect v2
        # A replay agent announces "replay", not the recorded type (which fusion never sees):
        # the Kinect v2 prior, as for any recording made with the simulator or a Kinect v2.
        "replay": SensorPrior("replay"),
        "azure_kinect": AZURE_BODY_TRACKING,
        # The same Body Tracking SDK on an Orbbec Femto (conventions.md §1.3).
        "femto": replace(AZURE_BODY_TRACKING, name="femto"),
        "rgb": RGB_MONO,
    }
)
"""The prior of each sensor type; unknown types get :data:`KINECT_V2` (:func:`prior_for`)."""

_warned: set[str] = set()


def prior_for(sensor_type: str, priors: Mapping[str, SensorPrior] = PRIORS) -> SensorPrior:
    """The prior of ``sensor_type``; an unknown type gets Kinect v2's, with one warning per type."""
    prior = priors.get(sensor_type)
    if prior is not None:
        return prior
    if sensor_type not in _warned:
        _warned.add(sensor_type)
        _log.warning("no fusion prior for sensor type %r: using Kinect v2's", sensor_type)
    return KINECT_V2


def priors_of(sensor_types: Sequence[str]) -> list[SensorPrior]:
    """Each view's prior, in order (:func:`prior_for` on each type)."""
    key = tuple(sensor_types)
    kept = _priors_of.get(key)
    if kept is None:  # frames repeat the same sensors: each sequence of types looked up once
        if len(_priors_of) >= _KEPT:
            _priors_of.clear()
        kept = _priors_of[key] = tuple(prior_for(t) for t in sensor_types)
    return list(kept)


def distinct_priors(
    priors: Sequence[SensorPrior],
) -> tuple[list[SensorPrior], npt.NDArray[np.intp]]:
    """The distinct priors (first-seen order) and each view's index among them, (N,) read-only.

    Frames repeat the same sequence of prior objects: the answer is kept per sequence, by the
    objects' identities (the objects kept with it, so that no id is reused meanwhile), which
    is cheaper than hashing a frozen dataclass (all its fields, each time).
    """
    key = tuple(map(id, priors))
    kept = _distinct_of.get(key)
    if kept is None:
        if len(_distinct_of) >= _KEPT:
            _distinct_of.clear()
        # Views share a handful of prior objects: each object hashed once, not once per view.
        objects = dict(zip(key, priors, strict=True))  # first-seen order; one object per id
        index: dict[SensorPrior, int] = {}
        of_object = {k: index.setdefault(prior, len(index)) for k, prior in objects.items()}
        of_view = np.array([of_object[k] for k in key], dtype=np.intp)
        of_view.flags.writeable = False
        kept = _distinct_of[key] = (tuple(priors), list(index), of_view)
    return list(kept[1]), kept[2]


_KEPT: Final = 64
"""Sequences of types (of priors) :func:`priors_of` (:func:`distinct_priors`) keeps."""
_priors_of: dict[tuple[str, ...], tuple[SensorPrior, ...]] = {}
_distinct_of: dict[
    tuple[int, ...], tuple[tuple[SensorPrior, ...], list[SensorPrior], npt.NDArray[np.intp]]
] = {}


_TRUNK: Final = (J.SPINE_BASE, J.SPINE_MID, J.NECK, J.HEAD, J.SPINE_SHOULDER, J.SHOULDER_LEFT,
                 J.SHOULDER_RIGHT, J.HIP_LEFT, J.HIP_RIGHT)  # fmt: skip
_EXTREMITIES: Final = (J.HAND_LEFT, J.HAND_RIGHT, J.HAND_TIP_LEFT, J.HAND_TIP_RIGHT,
                       J.THUMB_LEFT, J.THUMB_RIGHT, J.FOOT_LEFT, J.FOOT_RIGHT)  # fmt: skip
JOINT_CLASSES: Final = np.array(
    [0 if j in _TRUNK else 2 if j in _EXTREMITIES else 1 for j in JointId], dtype=np.intp
)
"""Each joint's class for ``SensorPrior.error_m``: 0 trunk (spine, neck, head, hips,
shoulders), 1 limb (elbows, wrists, knees, ankles), 2 extremity (hands, hand tips, thumbs,
feet); JointId order."""


SECTORS: Final = 8
"""Directions of a sensor around the person its errors are learned in, 45° apart: in front,
front-left, at the person's left, back-left, behind, back-right, right, front-right."""


def prior_variances(prior: SensorPrior, settings: FusionSettings) -> npt.NDArray[np.float64]:
    """(25, B) the variance (m²) ``prior`` gives each joint in each bin of
    :mod:`fusion.rig_errors` (sector × state × distance, ``rig_errors.bin_of``).

    Between in front (1), at the side (``side_ratio``) and behind (``back_ratio``) the ratio
    follows ``sin²`` of the sensor's direction off the person's front (or back). A state whose
    weight is 0 gets an infinite variance (it never counts)."""
    base = np.asarray(prior.error_m, dtype=np.float64)[JOINT_CLASSES] ** 2
    _, inferred, tracked = prior.table(settings)
    inferred_ratio = tracked / inferred if inferred > 0 else math.inf
    out = np.empty((len(base), SECTORS * 4))
    for sector in range(SECTORS):
        angle = 2 * math.pi * sector / SECTORS
        side = math.sin(angle) ** 2
        ends = 1.0 if math.cos(angle) > 0 else prior.back_ratio
        facing = ends + (prior.side_ratio - ends) * side
        for state, ratio in ((0, 1.0), (2, inferred_ratio)):
            for far, distance in ((0, 1.0), (1, prior.far_ratio)):
                out[:, sector * 4 + state + far] = base * facing * ratio * distance
    return out
