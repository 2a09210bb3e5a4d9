"""What fusion does, term by term: the full method by default, every term switchable.

Docs: docs/fusion.md §9 (the TOML file a deployment sets them with).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from skelfuse.protocol.constants import HEARTBEAT_INTERVAL_S


@dataclass(frozen=True, slots=True)
class FusionSettings:
    """Parameters of fusion and tracking (see ``docs/fusion.md``).

    The defaults are the full method. The benchmark's method ladder (tracking-state weights only,
    + bone length, + range of motion, + mirrored-view correction, + filter) switches terms off
    with ``dataclasses.replace``.
    """

    state_weights: tuple[float, float, float] = (0.0, 0.3, 0.7)
    """Confidence of a NotTracked / Inferred / Tracked joint (report A's values)."""
    association_gate_m: float = 0.5
    """Views farther apart than this (trunk distance) are never the same person."""
    track_timeout_s: float = 1.0
    """A person unseen by every sensor for this long is gone; a later return gets a new id."""
    track_min_frames: int = 3
    """A new person is published after this many consecutive fused frames (no one-frame ghosts)."""

    # --- body-based confidence (fusion/confidence.py) ------------------------------------------
    use_bone_length: bool = True
    """Multiply in the bone-length term (report A), propagated outward from SpineBase."""
    bone_length_scale_m: float = 0.08
    """Bone-length term ``exp(−|l − l_ref| / scale)``: 0.88 at 1 cm off, 0.29 at 10 cm."""
    bone_estimate_window: int = 300
    """Online reference lengths: median of the last this many good observations per bone."""
    bone_estimate_min_samples: int = 10
    """An online reference bone length is used once it has this many observations."""
    bone_estimate_symmetric: bool = True
    """Left and right bones share their observations in the online estimate (one length each)."""
    bone_estimate_lock_samples: int | None = None
    """An online reference bone length stops changing once it has this many good observations
    (None: it follows the last ``bone_estimate_window`` observations for ever)."""
    use_range_of_motion: bool = True
    """Multiply in the range-of-motion term (anatomical limits table in fusion/confidence.py)."""
    rom_scale_deg: float = 15.0
    """Range-of-motion term ``exp(−excess / scale)`` for an angle ``excess`` degrees outside."""
    use_facing: bool = True
    """Multiply in how frontally the person faces each sensor."""
    facing_power: float = 2.0
    """Facing term ``floor + (1 − floor)·|cos θ|^power`` (θ: person's yaw off the sensor)."""
    facing_floor: float = 0.1
    facing_back_factor: float = 0.5
    """The facing term is multiplied by this when the sensor sees the person's back."""
    correct_view_yaw: bool = False
    """Turn each view about the vertical to the facing of the views seen most frontally
    (removes each sensor's bias of turning the skeleton towards itself)."""
    yaw_max_deg: float = 60.0
    """Views needing a larger turn are left as they are."""
    use_distance: bool = False
    """Multiply in the distance term: 1 inside ``distance_best_m``, Gaussian fall-off outside.
    Off by default: on the simulated rigs it cost MPJPE in 6 of 8 benchmark groups (far views
    are often the frontal ones, and depth noise is small next to drift and inferred joints;
    docs/benchmarks.md). Worth trying where far views are visibly worse."""
    distance_best_m: tuple[float, float] = (1.5, 3.0)
    distance_scale_m: float = 1.0
    outlier_scale_m: float = 0.0
    """Robust re-weighting (Cauchy, one pass) of views far from the weighted mean; 0 = off."""

    # --- mirrored views (fusion/mirror.py) ----------------------------------------------------
    use_mirror_correction: bool = True
    """Detect views whose left and right are swapped (person facing away) and swap them back."""
    mirror_geometry_weight_m: float = 0.15
    """Cost (metres of disagreement) of a labelling that contradicts where the person faces."""
    mirror_hysteresis_m: float = 0.05
    """Extra cost of changing a view's labelling from the previous step."""
    mirror_track_weight: float = 1.0
    """Weight of the agreement with the person's previous fused skeleton."""
    mirror_anatomy_weight_m: float = 0.1
    """Cost per joint out of its range of motion under a labelling (bent knees look
    hyperextended and feet point backwards when left and right are swapped)."""
    mirror_walk_check_s: float = 0.5
    """A person whose fused skeleton faces against the way it walks for this long is taken to
    be mirrored as a whole (every view's labelling and the track swapped); 0 = off. People walk
    forwards: a track that started mirrored can otherwise stay so, since every view is then
    labelled to agree with it (docs/fusion.md)."""
    mirror_walk_min_speed_mps: float = 0.5
    """Walking speed from which the walking direction is trusted (side steps and shuffles are
    slower; brisk walking backwards for longer than ``mirror_walk_check_s`` is misread)."""

    # --- temporal filter (fusion/filters.py) --------------------------------------------------
    filter: Literal["one_euro", "kalman", "none", "kalman_ca"] = "kalman_ca"
    """``none``, ``one_euro``, ``kalman`` or ``kalman_ca`` (the default; fields ``kalman_ca_*``
    below); applied per person after fusion. ``kalman_ca`` is the default since it halves One
    Euro's lag at lower jitter (docs/benchmarks.md "Lag against the truth"); ``one_euro`` was the
    default before and stays available."""
    one_euro_min_cutoff_hz: float = 1.5
    one_euro_beta: float = 10.0
    one_euro_d_cutoff_hz: float = 1.0
    kalman_accel_std: float = 8.0
    """Constant-velocity Kalman: white acceleration noise, m/s² (per axis)."""
    kalman_meas_std_m: float = 0.03
    """Constant-velocity Kalman: measurement noise of a fused joint, metres (per axis)."""
    kalman_predict_s: float = 0.0
    """Extrapolate the Kalman output this far ahead (compensates latency; adds overshoot)."""
    enforce_bone_lengths: bool = True
    """Give each fused skeleton the person's reference bone lengths."""
    bone_length_fit: Literal["projection", "chain"] = "projection"
    """How: ``projection`` moves both ends of each bone, as little as possible in all
    (fusion.weighted.project_bone_lengths); ``chain`` rescales bone after bone outward from
    SpineBase, keeping each parent where it is (fusion.weighted.enforce_bone_lengths)."""
    bone_fit_iterations: int = 3
    """Passes of ``projection`` before its exact finishing pass."""

    # --- drift detection (fusion/drift.py; issue 10 item 5) -----------------------------------
    drift_detection: bool = False
    """Watch every sensor for a move since its calibration (a bump): flags in ``/api/sensors``,
    ``/metrics`` and the viewer. Observes only: the fused output is the same either way. Off by
    default until the lead decides: it flags change since a per-pair baseline taken after each
    calibration change (so a calibration's own error is not flagged, but neither is a bump
    before the baseline; docs/calibration.md)."""
    drift_window_s: float = 6.0
    """Sliding window of fusion instants the rigid correction is estimated over (seconds)."""
    drift_check_interval_s: float = 1.0
    """Seconds of fusion instants between two estimates."""
    drift_threshold_deg: float = 1.2
    """A correction rotating more than this (degrees) counts against the sensor."""
    drift_threshold_mm: float = 20.0
    """A correction shifting the person more than this (millimetres) counts against the sensor."""
    drift_confirm_checks: int = 3
    """Consecutive estimates over a threshold that flag a sensor (and under that clear it)."""

    # --- birth labelling that cannot lock in a guess (fusion/labels.py; issue 10 item 1) ------
    mirror_redecide: bool = True
    """Re-decide a whole person's left and right from the anatomy of all its views, standing
    still included: evidence against the labels (bent knees and feet pointing the wrong way
    under them, summed over views) that builds up past ``mirror_redecide_evidence`` swaps the
    person (every view's labelling and the track). A view that cannot tell left from right
    (seen from behind with the legs out of view, one view alone) adds next to nothing, so the
    guess it made at birth is undone as soon as a front or side view sees the person
    (docs/fusion.md §6)."""
    mirror_redecide_evidence: float = 1.5
    """Evidence (Σ over views of the joints out of range of motion as labelled minus as
    swapped, in joints) that swaps a person, summed over time with ``mirror_redecide_tau_s``."""
    mirror_redecide_tau_s: float = 0.2
    """Time constant (seconds) of the running sum of evidence: a glitch of a frame or two
    cannot reach the threshold, evidence that persists does within a few frames."""
    mirror_redecide_young_s: float = 2.0
    """A person younger than this (seconds since birth) re-decides from one step's evidence
    when a sensor joins it (threshold halved, the running sum restarted)."""

    # --- priors per sensor type (fusion/priors.py; issue 10 item 4) -----------------------------
    use_sensor_priors: bool = True
    """Each view uses its sensor type's prior (fusion/priors.py, docs/fusion.md §7 "Priors per
    sensor type"): state table, noise, facing model, range-of-motion scale, and no bone-length
    term for a fixed-length body model (Azure Kinect / Femto Body Tracking). Kinect v2, sim and
    replay views get the settings' values, so the output changes only where other types join."""

    # --- per-joint view reliability (fusion/reliability.py; issue 10 item 2) -------------------
    use_view_reliability: bool = False
    """Weigh each view's joint by how well that view sees it: the lean of a side view towards
    its sensor (largest at the ankles, feet and hands), the jitter growing with depth, and
    self-occlusion by the trunk, as an inverse error variance relative to the person's best
    view of that joint (docs/fusion.md §7). It models per joint what ``use_facing`` models per
    view, so the two are meant to be used one or the other (measured: reliability in place of
    facing is best, docs/benchmarks.md)."""
    view_lean_fraction: float = 0.5
    """Share of the person's yaw relative to a sensor by which its view turns towards it (the
    Kinect v2 facing bias: 0.5 in the simulator, measured on NTU RGB+D)."""
    view_error_m: tuple[float, float, float] = (0.021, 0.035, 0.06)
    """The error floor (metres, 3-D norm) of trunk, limb and extremity joints in a frontal view:
    √3 × the simulator's per-axis systematic error (12, 20, 35 mm)."""
    view_jitter_per_m2: float = 0.001
    """Jitter growth with the squared distance to the sensor (metres per m², Kinect v2)."""
    view_occlusion_m: float = 0.08
    """Extra error (metres) of a joint hidden from the sensor: by the person's own trunk, or
    reported Inferred."""

    # --- damped-acceleration Kalman filter (fusion/filters_ca.py; issue 10 item 3) ----------
    kalman_ca_jerk_std: float = 3.0
    """``filter = "kalman_ca"``: white jerk, square root of its spectral density (m/s^2.5)."""
    kalman_ca_meas_std_m: float = 0.03
    """``filter = "kalman_ca"``: measurement noise of a fused joint, metres (per axis)."""
    kalman_ca_accel_tau_s: float = 0.1
    """``filter = "kalman_ca"``: time constant (s) with which the acceleration decays to 0."""
    kalman_ca_predict_s: float = 0.006
    """``filter = "kalman_ca"``: output extrapolated this far ahead (cancels the lag)."""
    kalman_ca_jerk_per_speed: float = 30.0
    """``filter = "kalman_ca"``: jerk added per m/s of a coordinate's speed (m/s^2.5 per m/s):
    smooth when still, quick when moving, as One Euro's ``beta``."""

    # --- mirror labels: the person's facing without the sensors' yaw bias (fusion/labels.py) --
    mirror_unbiased_facing: bool = True
    """The mirror labels' geometry term compares each sensor with the person's facing from the
    last step's labelled views, each view's turn towards its sensor (``view_lean_fraction``)
    taken out (fusion.labels.unbiased_facings), instead of the fused skeleton's facing, which
    inherits those turns (docs/fusion.md §6). On by default since 2026-11-22 (with
    ``mirror_redecide_views = 2``: crossing wrong labels 1.19 % → 0.35 %, docs/benchmarks.md)."""
    mirror_redecide_views: int = 2
    """``mirror_redecide``: an old person (not younger than ``mirror_redecide_young_s``) with at
    least this many views is turned over as a whole only when at least this many of them have
    evidence against their labels (≥ 0.5 joints) at that step; otherwise those views alone are
    turned over (fusion.labels.views_alone). 1: always the whole person (the default before
    2026-11-22); 2 is the default."""

    # --- time alignment: when an output instant is fused (fusion/alignment.py; issue 11 item 1) --
    alignment: Literal["aligned", "phased", "deadline"] = "deadline"
    """When the engine fuses an output instant (docs/fusion.md §2): ``aligned`` once every live
    sensor has a frame at or after it, on a grid of phase 0 (the rule before issue 11, and what
    offline replay always uses); ``phased`` the same rule on a grid whose phase follows the
    sensors' capture phases: 4–7 ms less wait on average in the accuracy scenarios (up to 12
    ms for a rig), MPJPE within 0.25 mm of ``aligned`` (docs/benchmarks.md "Alignment
    policies"); ``deadline`` (the default) as ``phased``, but at the latest
    ``alignment_deadline_s`` after the instant, late sensors carried forward: with the
    ``alignment_*`` defaults below +0.19 to +0.67 mm against ``aligned`` in those scenarios
    (mean of 3 runs each), and capture → client 8.7 / 10.3 ms p50 / p99 for 10 sensors at
    random phases (2026-11-24 20:26, raw clients; ``phased`` 33.7 / 43.8 on a slower day;
    docs/benchmarks.md "Load"). On a
    link with delivery jitter it waits as ``phased`` does (``alignment_jitter_fallback_s``)."""
    alignment_deadline_s: float = 0.007
    """``deadline``: an instant is fused at the latest this long after it (server clock,
    seconds); it must cover the agents' usual delivery delay (capture to the server). 7 ms:
    +0.19 to +0.67 mm against ``aligned`` in the accuracy scenarios, 10 ms +0.13 to +0.72, 5
    ms +0.32 to +1.03 (docs/benchmarks.md "Alignment policies")."""
    alignment_max_extrapolation_s: float = 0.034
    """``deadline``: a late sensor's newest frame is extrapolated to the instant by at most this
    much (seconds, about one frame period at 30 fps); a sensor further behind is left out."""
    # The late-sensor treatment under ``deadline`` (fusion/extrapolation.py, fusion/track_motion.py,
    # fusion/alignment.py; issue 11's raw latency target): how a late view is carried forward and
    # where the grid is put. None of these changes ``aligned`` or ``phased``.
    alignment_predictor: Literal["views", "track", "own"] = "views"
    """``deadline``: a late sensor's bodies are carried to the instant by what the same person's
    on-time views saw happen meanwhile, per joint (``views``, fusion/extrapolation.py; the joints
    none of them saw as ``track``), by their person's motion as its filter estimates it
    (``track``: it lags a change of pace), or linearly from the sensor's own two newest frames
    (``own``, the first version: their frame-to-frame noise makes a poor velocity)."""
    alignment_predict_acceleration: bool = True
    """``deadline``, ``track``: use the filter's acceleration as well as its velocity."""
    alignment_grid: Literal["wait", "horizon"] = "horizon"
    """``deadline``: put the grid where the late sensors are carried least (``horizon``: the
    replayed sum of squared horizons) or where the wait for the last sensor is least (``wait``,
    as ``phased``; the first version). At 10 ms ``horizon`` cost less MPJPE in 7 of the 8
    accuracy scenarios and waited 0.9–2.5 ms less (docs/benchmarks.md "Alignment policies")."""
    alignment_skip_expected_late: bool = True
    """``deadline``: an instant does not wait for a sensor whose frame, by the phases and delays
    observed, comes after the deadline anyway; it is fused once the others are in (at the
    deadline when every sensor is expected late)."""
    alignment_wait_for_phase: bool = True
    """``deadline``: until the grid's phase is first chosen (every sensor has 30 frames: about a
    second) instants wait for every sensor as under ``phased``; before, the grid is wherever the
    first frames put it and late sensors are carried by up to a period (in the accuracy
    scenarios that first second cost ~0.5 mm of MPJPE over a 6 s run)."""
    alignment_jitter_fallback_s: float = 0.002
    """``deadline``: while the sensors' delivery delays scatter wider than this (seconds: the
    median over sensors of each one's p90 − p10 over its last 60 frames, judged once a second;
    back under two thirds of it, the deadline returns), instants wait for every sensor as under
    ``phased``. On such a link (Wi-Fi) a sensor expected on time misses the deadline at random
    and is carried most of a period: with 1 or 3 ms of exponential delivery jitter the deadline
    cost +0.2 to +1.6 / +1.0 to +3.7 mm against ``aligned``, with this fall-back +0.0 to +0.3
    / −0.0 to +0.2 mm (docs/benchmarks.md "Alignment policies"). Loopback scatters ~0.5 ms.
    0: never."""
    alignment_deadline_grace_s: float = 0.003
    """``deadline`` with ``alignment_skip_expected_late`` (which judges who is expected on
    time, by the same replay that puts the grid): at the deadline, while a sensor expected on
    time has no frame at or after the instant, the instant waits up to this much
    longer (seconds) before carrying that sensor. Below the jitter fall-back's scatter, such a
    sensor misses the deadline by a hair at random and would be carried from its frame before,
    most of a period: with 0.5 ms of exponential delivery jitter this cut the cost against
    ``aligned`` in 26 of 30 runs (by 0.08 mm on average, up to 0.27), at most 0.05 ms more mean
    wait; without jitter it never waits (the same output to the bit); docs/benchmarks.md
    "Alignment policies". 0: never."""


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
