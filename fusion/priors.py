"""What fusion assumes about each kind of sensor: one :class:`SensorPrior` per ``sensor_type``.

The sensor type is what an agent announces in its hello (``protocol.wire.SENSOR_TYPES``) and
:class:`fusion.sensors.SensorState` keeps; :func:`fusion.pipeline.views_at` copies it onto each
:class:`fusion.views.View`, and :func:`fusion.confidence.body_weights` /
:func:`fusion.view_factors.view_factors` use each view's prior (when
``FusionSettings.weights.sensor_priors`` is on). The table and what each value rests on:
docs/fusion.md §7, "Priors per sensor type".

A field left ``None`` takes the :class:`FusionSettings` value, so the Kinect v2 prior *is* the
settings (a deployment's TOML file keeps tuning it) and its numbers are today's exactly.

What is measured and what is not: the Kinect v2 values are the ones the simulator benchmarks
(docs/benchmarks.md), and the simulator models a Kinect v2 only. No Azure Kinect or Femto was
available: their entries rest on the SDK's documentation and on public multi-view recordings
(``shared/conventions.md`` §1.2, §1.6, §5), not on a benchmark. ``rgb`` (one ordinary camera
through MediaPipe Pose, agent/sources/mono.py) rests on the four-camera clip's figures of issue 14.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.settings import FusionSettings

_log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class SensorPrior:
    """What fusion assumes about one kind of sensor (``None``: the FusionSettings value).

    state_weights: weight of a NotTracked / Inferred / Tracked joint. For Azure Kinect Body
        Tracking (and Femto through it) the agent maps confidence NONE → NotTracked,
        LOW → Inferred, MEDIUM and HIGH → Tracked (agent/sources/azure_kinect.py), so the three
        entries are the weights of NONE, LOW and MEDIUM/HIGH.
    noise_scale: the sensor's joint position noise relative to a Kinect v2 (1: the same). A
        view's weights are multiplied by ``1 / noise_scale²`` (inverse-variance weighting).
    facing_power, facing_floor, facing_back_factor: the facing term
        (:func:`fusion.view_factors.facing_factors`).
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
    state_weights: tuple[float, float, float] | None = None
    noise_scale: float = 1.0
    facing_power: float | None = None
    facing_floor: float | None = None
    facing_back_factor: float | None = None
    may_mirror: bool = True
    rom_scale: float = 1.0
    fixed_bone_lengths: bool = False
    depth_noise_ratio: float = 1.0

    def table(self, settings: FusionSettings) -> tuple[float, float, float]:
        """The state weights in force: this prior's, else the settings'."""
        return settings.weights.state_weights if self.state_weights is None else self.state_weights

    def facing(self, settings: FusionSettings) -> tuple[float, float, float]:
        """(power, floor, back_factor) in force for the facing term."""
        s = settings
        return (
            s.weights.facing_power if self.facing_power is None else self.facing_power,
            s.weights.facing_floor if self.facing_floor is None else self.facing_floor,
            s.weights.facing_back_factor
            if self.facing_back_factor is None
            else self.facing_back_factor,
        )


KINECT_V2: Final = SensorPrior("kinect_v2")
"""Everything from FusionSettings: the values the simulator benchmarks."""

AZURE_BODY_TRACKING: Final = SensorPrior(
    "azure_kinect",
    # conventions.md §1.6 maps LOW like Kinect v2's Inferred and MEDIUM/HIGH like Tracked; no
    # measurement here says an Azure LOW joint is better or worse than a v2 Inferred one.
    state_weights=(0.0, 0.3, 0.7),
    # Not measured here; published comparisons put Azure's depth noise at or below Kinect v2's,
    # so 1 (equal) is the cautious choice until a recording says more.
    noise_scale=1.0,
    # Its tracker flips front/back for some people and outfits (Azure-Kinect-Sensor-SDK issues
    # #575, #1330): the mirror step must keep checking its views.
    may_mirror=True,
    rom_scale=1.0,
    # conventions.md §5: bone lengths vary 2-8 mm per track on two Azure Kinects (up to 69 mm on
    # Kinect v2): a fixed-length body model.
    fixed_bone_lengths=True,
)
"""Azure Kinect Body Tracking (k4abt 1.x): Azure Kinect DK and Orbbec Femto via the K4A wrapper."""

RGB_MONO: Final = SensorPrior(
    "rgb",
    # Visibility predicts MediaPipe's error poorly (issue 14: 23 % of joints at visibility
    # >= 0.95 were more than 0.2 torso off in 2-D), so Inferred is not far below Tracked.
    state_weights=(0.0, 0.3, 0.5),
    # Across the image a landmark is good to a few pixels (millimetres at 2-3 m), but the
    # 3-D shape MediaPipe guesses is 80-90 mm off after Procrustes alignment on the clip:
    # about twice a Kinect v2's joint noise, a quarter of its weight.
    noise_scale=2.0,
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
The figures are the issue-14 measurements on the four-camera clip (one person, one scene); the
split of the noise between across and along the ray is an estimate from them, not a fit."""

PRIORS: Final[Mapping[str, SensorPrior]] = MappingProxyType(
    {
        "kinect_v2": KINECT_V2,
        "sim": SensorPrior("sim"),  # the simulator models a Kinect v2
        # A replay agent announces "replay", not the recorded type (which fusion never sees):
        # the Kinect v2 prior, as for any recording made with the simulator or a Kinect v2.
        "replay": SensorPrior("replay"),
        "azure_kinect": AZURE_BODY_TRACKING,
        "femto": SensorPrior(
            "femto",
            state_weights=AZURE_BODY_TRACKING.state_weights,
            noise_scale=AZURE_BODY_TRACKING.noise_scale,
            may_mirror=AZURE_BODY_TRACKING.may_mirror,
            rom_scale=AZURE_BODY_TRACKING.rom_scale,
            fixed_bone_lengths=AZURE_BODY_TRACKING.fixed_bone_lengths,
        ),  # the same Body Tracking SDK on an Orbbec Femto (conventions.md §1.3)
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
