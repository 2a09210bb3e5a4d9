"""What fusion does, in a few groups of knobs: the full method by default, every term switchable.

Each group is a frozen dataclass read as ``settings.group.knob`` (``s.mirror.walk_check_s``);
a deployment's TOML file has one table per group (``[fusion.mirror]``, fusion/config.py).
Change one knob with ``dataclasses.replace``::

    s = replace(s, mirror=replace(s.mirror, walk_check_s=0.0))
    s = FusionSettings(smoothing=SmoothingSettings(filter="none"))

Docs: docs/fusion.md §9 (the parameters and the TOML file a deployment sets them with).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from skelfuse.protocol.constants import HEARTBEAT_INTERVAL_S

FilterKind = Literal["one_euro", "kalman", "none", "kalman_ca"]
AlignmentPolicy = Literal["aligned", "phased", "deadline"]
LatePredictorKind = Literal["views", "track", "own"]


@dataclass(frozen=True, slots=True)
class TrackingSettings:
    """Who is who over time: views grouped into persons, persons born and dropped
    (fusion/identity.py)."""

    gate_m: float = 0.5
    """Views whose trunks are farther apart than this are never one person; raise it for
    sensors far off their calibration, lower it when people stand closer than that."""
    timeout_s: float = 1.0
    """A person unseen by every sensor this long is dropped (a return gets a new id); raise it
    where people are often hidden for longer."""
    min_frames: int = 3
    """A new person is published after this many consecutive fused steps; 1 publishes at once
    (tests, a single known person), more hides ghosts longer."""


@dataclass(frozen=True, slots=True)
class WeightSettings:
    """How much each view's joint counts in the weighted mean besides its sensor's learned
    error (fusion/confidence.py, fusion/weigh.py, fusion/priors.py)."""

    state_weights: tuple[float, float, float] = (0.0, 0.3, 0.7)
    """Kinect v2's prior of a NotTracked / Inferred / Tracked joint, each in [0, 1]: an
    Inferred joint's variance starts at Tracked / Inferred times a Tracked one's, and a weight
    of 0 leaves the state out; learning (``[fusion.learning]``) then replaces the ratio."""
    bone_length: bool = True
    """Weigh down joints whose bones are off the person's reference lengths; off to compare
    with the state weights alone."""
    bone_length_scale_m: float = 0.08
    """Bone-length term ``exp(−|l − l_ref| / scale)``; larger forgives noisier sensors."""
    range_of_motion: bool = True
    """Weigh down joints bent beyond anatomical limits; off to compare without it."""
    rom_scale_deg: float = 15.0
    """Range-of-motion term ``exp(−excess / scale)``; larger forgives poses near the limits
    (athletes, dancers)."""
    view_bins: bool = True
    """Weigh each view's joints by where its sensor stands relative to the person and how far
    (their bins of the learned error, fusion/rig_errors.py); off: by tracking state alone
    (report A's baseline, for comparison)."""
    sensor_priors: bool = True
    """Each view starts from its sensor type's prior (fusion/priors.py: errors, state table,
    no bone-length term for fixed-length body models); off to treat every type as Kinect v2."""
    view_lean_fraction: float = 0.5
    """Share of the person's yaw off a sensor by which its view turns towards it (also used by
    the mirror labels' unbiased facing); set it to what your sensor type is measured to do."""


@dataclass(frozen=True, slots=True)
class LearningSettings:
    """Each sensor's error learned from the rig, per joint and what the view sees
    (fusion/rig_errors.py; docs/fusion.md §7)."""

    enabled: bool = True
    """Learn each sensor's error from its residuals to the other views; off keeps every
    sensor at its type's prior (fusion/priors.py)."""
    forget_s: float = 30.0
    """Time constant (seconds of a sensor seeing someone) of the evidence's exponential
    forgetting: a moved or degraded sensor is re-learned in about this long."""
    prior_samples: float = 60.0
    """Weight of a sensor type's prior, in views of a joint (60: two seconds of one sensor at
    30 fps); larger trusts the prior longer."""
    bin_samples: float = 30.0
    """Weight of a sensor's overall level in each of its bins, in views of a joint; larger
    keeps rarely seen bins (backs, far views) nearer the sensor's overall level."""
    far_m: float = 2.5
    """Views of a person farther than this (metres, horizontal) are learned apart."""
    cap: float = 4.0
    """A residual counts at most this many times its expected square: what is learned is a
    view's typical error, a glitch or a wrong label no more than a few times it (the Student-t
    weighting deals with those frame by frame)."""
    robust_dof: float = 4.0
    """Degrees of freedom of the Student-t weighting of views far off the others (a glitch
    weighs less); 0 turns it off."""


@dataclass(frozen=True, slots=True)
class MirrorSettings:
    """Views whose left and right are swapped (a person facing away) and whole persons
    labelled the wrong way round (fusion/mirror.py, fusion/labels.py; docs/fusion.md §6)."""

    enabled: bool = True
    """Detect mirrored views and swap them back; off only to compare without it."""
    geometry_weight_m: float = 0.15
    """Cost (metres of disagreement) of a labelling against where the person faces; raise it
    when views disagree little but facings are reliable."""
    hysteresis_m: float = 0.05
    """Extra cost of changing a view's labelling from the last step; raise it if labels
    flicker, lower it if they are slow to flip."""
    track_weight: float = 1.0
    """Weight of the agreement with the person's last fused skeleton; lower it if a wrong
    track keeps views wrong."""
    anatomy_weight_m: float = 0.1
    """Cost per joint out of its range of motion under a labelling; 0 ignores anatomy in the
    labels (poses beyond the usual limits)."""
    walk_check_s: float = 0.5
    """A person facing against the way it walks this long is turned over as a whole; 0 turns
    the check off where people walk backwards on purpose (dance, sport)."""
    walk_min_speed_mps: float = 0.5
    """Walking speed from which the walking direction is trusted; raise it if brisk
    backwards walking is common."""
    redecide: bool = True
    """Re-decide a whole person's left and right from the anatomy of all its views, so that a
    guess made at birth (seen from behind) is undone; off to keep the birth labels."""
    redecide_evidence: float = 1.5
    """Evidence (joints out of range as labelled minus as swapped, summed over views and time)
    that turns a person over; raise it if persons are turned over wrongly."""
    redecide_tau_s: float = 0.2
    """Time constant (seconds) of the running sum of evidence; longer ignores longer glitches
    but turns over later."""
    redecide_young_s: float = 2.0
    """A person younger than this (seconds) re-decides from one step's evidence when a sensor
    joins it; longer trusts birth labels less for longer."""
    redecide_views: int = 2
    """An old person with at least this many views is turned over as a whole only when this
    many views doubt their labels (else those views alone); 1 always turns the whole person."""
    limbs: bool = True
    """Put right a single arm or leg pair a view reports left for right, by the other views
    (or the track when at most two views see the person; fusion/limb_labels.py)."""
    unbiased_facing: bool = True
    """The labels' geometry term uses the person's facing with each view's turn towards its
    sensor taken out (``weights.view_lean_fraction``); off uses the fused skeleton's facing."""


@dataclass(frozen=True, slots=True)
class SmoothingSettings:
    """The temporal filter applied per person after fusion (fusion/filters.py; docs/fusion.md
    §8)."""

    filter: FilterKind = "kalman_ca"
    """``kalman_ca`` (damped acceleration, least lag), ``kalman`` (constant velocity),
    ``one_euro`` (smoother in place, more lag; offline analysis) or ``none`` (raw fusion)."""
    one_euro_min_cutoff_hz: float = 1.5
    """One Euro: cutoff when still; lower smooths a still person more."""
    one_euro_beta: float = 10.0
    """One Euro: cutoff growth with speed; larger lags less in fast motion, passes more noise."""
    one_euro_d_cutoff_hz: float = 1.0
    """One Euro: cutoff of the speed estimate; rarely worth changing."""
    kalman_accel_std: float = 8.0
    """Constant-velocity Kalman: acceleration noise (m/s², per axis); larger follows quick
    changes sooner, passes more noise."""
    kalman_meas_std_m: float = 0.03
    """Constant-velocity Kalman: a fused joint's noise (metres, per axis); set it to your rig's."""
    kalman_predict_s: float = 0.0
    """Constant-velocity Kalman: output extrapolated this far ahead (seconds) to hide latency;
    adds overshoot."""
    kalman_ca_jerk_std: float = 3.0
    """Damped-acceleration Kalman: jerk noise when still (m/s^2.5); larger follows sooner,
    passes more noise."""
    kalman_ca_meas_std_m: float = 0.03
    """Damped-acceleration Kalman: a fused joint's noise (metres, per axis); set it to your
    rig's."""
    kalman_ca_accel_tau_s: float = 0.1
    """Damped-acceleration Kalman: time constant (seconds) of the acceleration's decay to 0;
    longer keeps accelerating through a stop (overshoot)."""
    kalman_ca_predict_s: float = 0.006
    """Damped-acceleration Kalman: output extrapolated this far ahead (seconds) to cancel its
    lag; 0 for offline analysis."""
    kalman_ca_jerk_per_speed: float = 30.0
    """Damped-acceleration Kalman: jerk noise added per m/s of a coordinate's speed; larger is
    quicker when moving (as One Euro's ``beta``)."""


@dataclass(frozen=True, slots=True)
class BoneSettings:
    """The person's reference bone lengths, estimated online, and the fit that gives them to
    each fused skeleton (fusion/bones.py; docs/fusion.md §8)."""

    window: int = 300
    """A reference length is the median of this many last good observations per bone; longer
    settles slower and steadier."""
    min_samples: int = 10
    """A reference length is used once it has this many observations; more waits longer for a
    surer first length."""
    symmetric: bool = True
    """Left and right bones share one length; off for people with asymmetric limbs."""
    lock_samples: int | None = None
    """A reference length stops changing after this many good observations (None: it follows
    the window for ever); set it where lengths must not change (avatars, biomechanics)."""
    enforce: bool = True
    """Give each fused skeleton the person's reference lengths (moving both ends of each bone
    as little as possible); off to see the raw fused lengths."""
    fit_iterations: int = 3
    """Projection passes before the exact finishing pass; more moves the joints less unevenly,
    at more compute."""


@dataclass(frozen=True, slots=True)
class DriftSettings:
    """Watch every sensor for a move since its calibration (a bump; fusion/drift.py,
    docs/calibration.md). It only observes: the fused output is the same either way."""

    enabled: bool = False
    """Flag sensors that moved in ``/api/sensors``, ``/metrics`` and the viewer; on where
    sensors can be knocked and recalibration is possible."""
    window_s: float = 6.0
    """Window (seconds) of fusion instants each correction is estimated over; longer is
    steadier and slower to flag."""
    check_interval_s: float = 1.0
    """Seconds between two estimates; longer costs less compute and flags later."""
    threshold_deg: float = 1.2
    """A correction rotating more than this (degrees) counts against the sensor; raise it on a
    rig whose calibration wanders by more."""
    threshold_mm: float = 20.0
    """A correction shifting the person more than this (millimetres) counts against the sensor;
    raise it on a rig whose calibration wanders by more."""
    confirm_checks: int = 3
    """Consecutive estimates over (or under) a threshold that flag (or clear) a sensor; more
    flags fewer passing disturbances, later."""


@dataclass(frozen=True, slots=True)
class AlignmentSettings:
    """When an output instant is fused, and how late sensors are carried to it
    (fusion/alignment.py, fusion/extrapolation.py; docs/fusion.md §2). Offline replay always
    uses ``aligned``."""

    policy: AlignmentPolicy = "deadline"
    """``aligned`` waits for every sensor on a grid of phase 0; ``phased`` waits on a grid that
    follows the sensors' phases; ``deadline`` fuses at the latest ``deadline_s`` after the
    instant, carrying late sensors. ``phased`` where waiting matters less than every frame."""
    deadline_s: float = 0.007
    """``deadline``: an instant is fused at the latest this long after it (seconds, in
    (0, 0.1]); it must cover the agents' usual delivery delay, so raise it on slower links."""
    max_extrapolation_s: float = 0.034
    """``deadline``: a late sensor is carried forward at most this far (seconds, at most 0.1);
    further behind it is left out. About one frame period."""
    predictor: LatePredictorKind = "views"
    """``deadline``: carry a late sensor's bodies by what the person's on-time views saw
    meanwhile (``views``), by the person's filtered motion (``track``, which lags a change of
    pace; for a rig with a single sensor per person) or linearly from the sensor's own two
    newest frames (``own``, noisier)."""
    predict_acceleration: bool = True
    """``deadline``, ``track``: use the filter's acceleration as well as its velocity; off if
    late bodies overshoot."""
    grid: Literal["wait", "horizon"] = "horizon"
    """``deadline``: put the grid where late sensors are carried least (``horizon``) or where
    the wait for the last sensor is least (``wait``, lower latency)."""
    skip_expected_late: bool = True
    """``deadline``: do not wait for a sensor expected after the deadline anyway; off to wait
    for it until the deadline."""
    wait_for_phase: bool = True
    """``deadline``: until the grid's phase is first chosen (about a second) wait for every
    sensor as ``phased``; off to fuse at once from the first frames."""
    jitter_fallback_s: float = 0.002
    """``deadline``: while delivery delays scatter wider than this (seconds, at most 0.1) wait
    for every sensor as ``phased`` (Wi-Fi); 0 never falls back."""
    deadline_grace_s: float = 0.003
    """``deadline``: wait up to this much longer (seconds, at most 0.1) for a sensor expected on
    time that has not arrived; 0 never waits past the deadline."""


@dataclass(frozen=True, slots=True)
class FusionSettings:
    """Parameters of fusion and tracking, by group (see ``docs/fusion.md`` §9).

    The defaults are the full method. The benchmark's method ladder (tracking-state weights only,
    + bone length, + range of motion, + mirrored-view correction, + filter) switches terms off
    with ``dataclasses.replace``.
    """

    tracking: TrackingSettings = field(default_factory=TrackingSettings)
    weights: WeightSettings = field(default_factory=WeightSettings)
    learning: LearningSettings = field(default_factory=LearningSettings)
    mirror: MirrorSettings = field(default_factory=MirrorSettings)
    smoothing: SmoothingSettings = field(default_factory=SmoothingSettings)
    bones: BoneSettings = field(default_factory=BoneSettings)
    drift: DriftSettings = field(default_factory=DriftSettings)
    alignment: AlignmentSettings = field(default_factory=AlignmentSettings)


@dataclass(frozen=True, slots=True)
class HubSettings:
    """What the fusion engine reads: the method, the output grid and sensor liveness.

    The server's :class:`skelfuse.server.settings.Settings` extends it with the network's.
    """

    fusion: FusionSettings = field(default_factory=FusionSettings)
    output_hz: float = 30.0
    """Fused frames per second: instants on a fixed grid of the server clock."""
    max_wait_s: float = 0.1
    """Fusion waits at most this long for a late sensor before fusing without it."""
    interpolation_gap_s: float = 0.1
    """Frames further apart than this are not interpolated between (nearest is used)."""
    heartbeat_interval_s: float = HEARTBEAT_INTERVAL_S
