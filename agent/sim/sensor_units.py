"""Which error model a simulated sensor follows, and per-sensor random parameters for each.

Two error models share one interface (:class:`SimulatedSensor`): the Kinect v2 model
(:mod:`agent.sim.kinect_model`, which fusion's confidence was tuned on) and the depth body
tracker (:mod:`agent.sim.tracker_model`, errors of another structure). :class:`ErrorModel`
picks one, with every sensor at the model's defaults or each drawn at random.

Random units (``random_sensors``): every sensor of a rig is a different unit, good or bad, drawn
independently of where it stands. Each listed parameter is drawn on its own: ``factor`` ranges
multiply the model's default, log-uniformly (as many units are half as noisy as three times
as noisy); ``value`` ranges are uniform. Parameters not listed keep their defaults (field of
view, range, frame rate, the glitch and dropout durations).

Kinect v2 model (:data:`KINECT_SPREAD`): jitter (base and per m²), drift σ (trunk, limbs,
extremities), Inferred error ×0.5–×3; drift and Inferred correlation times ×0.5–×2; facing
bias 0.15–0.85; mirror threshold 95–125°; glitch and dropout rates ×0.3–×3.

Depth tracker model (:data:`TRACKER_SPREAD`): depth noise per m², across-ray noise, body-scale
error, side-view depth bias ×0.5–×3; depth-noise correlation time ×0.5–×2; lean 5–50° with
saturation 40–85° and left/right asymmetry −0.5–0.5; far-side gain 0.3–3; limb-swap rate,
glitch and dropout rates ×0.3–×3; glitch size ×0.5–×3; occlusion pull 0.2–0.9; mirror
threshold 100–130° with width 3–15°.

Fusion never reads any of this: it sees only what the sensors report on the wire.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, Final, Literal, Protocol, TypeVar

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.kinect_model import KinectV2Params, Observation, SimulatedKinect
from skelfuse.agent.sim.tracker_model import DepthTrackerParams, SimulatedDepthTracker
from skelfuse.protocol.transform import Matrix4

FloatArray = npt.NDArray[np.float64]
SensorParams = KinectV2Params | DepthTrackerParams


class SimulatedSensor(Protocol):
    """What every simulated sensor error model offers (as :class:`SimulatedKinect`)."""

    @property
    def params(self) -> SensorParams: ...

    @property
    def T_world_from_sensor(self) -> FloatArray: ...

    @property
    def position_m(self) -> FloatArray: ...

    def floor_plane(self) -> tuple[float, float, float, float]: ...

    def observe(self, persons_world: FloatArray, t_s: float) -> list[Observation]: ...


@dataclass(frozen=True, slots=True)
class Spread:
    """How one parameter varies between units: ``factor`` (log-uniform multiple of the
    default, ``low``–``high``) or ``value`` (uniform in ``low``–``high``)."""

    kind: Literal["factor", "value"]
    low: float
    high: float


def _factor(low: float, high: float) -> Spread:
    return Spread("factor", low, high)


def _value(low: float, high: float) -> Spread:
    return Spread("value", low, high)


_UNITS_STREAM: Final = 0x5E_4507  # mixed with a units seed: a stream of its own
_NOISE: Final = _factor(0.5, 3.0)
_TIME: Final = _factor(0.5, 2.0)
_RATE: Final = _factor(0.3, 3.0)
KINECT_SPREAD: Final[dict[str, Spread]] = {
    "jitter_base_m": _NOISE,
    "jitter_per_m2": _NOISE,
    "bias_trunk_m": _NOISE,
    "bias_limb_m": _NOISE,
    "bias_extremity_m": _NOISE,
    "inferred_error_m": _NOISE,
    "bias_tau_s": _TIME,
    "inferred_tau_s": _TIME,
    "facing_bias": _value(0.15, 0.85),
    "mirror_threshold_deg": _value(95.0, 125.0),
    "glitch_rate_hz": _RATE,
    "dropout_rate_hz": _RATE,
}
"""Per-unit spread of :class:`KinectV2Params` (module docstring)."""
TRACKER_SPREAD: Final[dict[str, Spread]] = {
    "depth_noise_per_m2": _NOISE,
    "across_noise_rad": _NOISE,
    "body_scale_sd": _NOISE,
    "side_depth_bias_m": _NOISE,
    "depth_noise_tau_s": _TIME,
    "lean_max_deg": _value(5.0, 50.0),
    "lean_saturation_deg": _value(40.0, 85.0),
    "lean_asymmetry": _value(-0.5, 0.5),
    "far_side_gain": _value(0.3, 3.0),
    "limb_swap_rate_hz": _RATE,
    "glitch_rate_hz": _RATE,
    "glitch_scale_m": _NOISE,
    "dropout_rate_hz": _RATE,
    "occlusion_pull": _value(0.2, 0.9),
    "mirror_threshold_deg": _value(100.0, 130.0),
    "mirror_width_deg": _value(3.0, 15.0),
}
"""Per-unit spread of :class:`DepthTrackerParams` (module docstring)."""


_Params = TypeVar("_Params", KinectV2Params, DepthTrackerParams)


def _draw(base: _Params, spread: dict[str, Spread], rng: np.random.Generator) -> _Params:
    """``base`` with every parameter of ``spread`` drawn (in the dataclass's field order)."""
    drawn: dict[str, Any] = {}  # every key a float field (the spreads name no others)
    for f in fields(base):
        rule = spread.get(f.name)
        if rule is None:
            continue
        if rule.kind == "factor":
            factor = math.exp(rng.uniform(math.log(rule.low), math.log(rule.high)))
            drawn[f.name] = float(getattr(base, f.name)) * factor
        else:
            drawn[f.name] = float(rng.uniform(rule.low, rule.high))
    return replace(base, **drawn)


def random_kinect_params(
    rng: np.random.Generator, base: KinectV2Params | None = None
) -> KinectV2Params:
    """One Kinect v2 unit: ``base`` (default: the model's defaults) spread by
    :data:`KINECT_SPREAD`."""
    return _draw(base or KinectV2Params(), KINECT_SPREAD, rng)


def random_tracker_params(
    rng: np.random.Generator, base: DepthTrackerParams | None = None
) -> DepthTrackerParams:
    """One depth-tracker unit: ``base`` (default: the model's defaults) spread by
    :data:`TRACKER_SPREAD`."""
    return _draw(base or DepthTrackerParams(), TRACKER_SPREAD, rng)


@dataclass(frozen=True, slots=True)
class ErrorModel:
    """Which error model a rig's simulated sensors follow: ``kind`` ``kinect`` (the Kinect v2
    model) or ``tracker`` (the depth body tracker); ``random_sensors``: each sensor a unit
    drawn at random (module docstring) instead of all at the model's defaults."""

    kind: Literal["kinect", "tracker"] = "kinect"
    random_sensors: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("kinect", "tracker"):
            raise ValueError(f"unknown sensor error model {self.kind!r}")

    def sensors(
        self,
        poses: Sequence[Matrix4],
        seeds: Sequence[int],
        units_seed: int,
        kinect_params: KinectV2Params | None = None,
    ) -> list[SimulatedSensor]:
        """One sensor per pose (4×4 ``T_world_from_sensor``), noise seeded by ``seeds``.

        ``kinect_params``: the fixed Kinect units' parameters (and the base the random ones are
        spread around); ``units_seed`` draws the random units, in order, on a stream of its own
        (no other random number changes with ``random_sensors``).
        """
        units_rng = np.random.default_rng([_UNITS_STREAM, units_seed])
        out: list[SimulatedSensor] = []
        for pose, seed in zip(poses, seeds, strict=True):
            if self.kind == "kinect":
                params = kinect_params
                if self.random_sensors:
                    params = random_kinect_params(units_rng, kinect_params)
                out.append(SimulatedKinect(pose, params, seed=seed))
            else:
                unit = random_tracker_params(units_rng) if self.random_sensors else None
                out.append(SimulatedDepthTracker(pose, unit, seed=seed))
        return out


DEFAULT_ERROR_MODEL: Final = ErrorModel()
"""Every sensor a Kinect v2 at the model's defaults (the benchmarks' default)."""
