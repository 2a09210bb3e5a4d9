"""Fusion settings from a deployment's TOML file, validated once at this trust boundary.

A file holds one table per group of :class:`~skelfuse.fusion.settings.FusionSettings`
(docs/fusion.md §9); what it leaves out keeps its default::

    [fusion.smoothing]
    filter = "kalman"          # kalman_ca (default) | one_euro | kalman | none

    [fusion.mirror]
    walk_check_s = 0           # dance: people walk backwards on purpose

The flat keys of before (``[fusion]`` / ``mirror_walk_check_s = 0``) are still read, with one
DeprecationWarning naming each one's new place (:data:`RENAMED`); a key whose setting was
removed is refused with the reason (:data:`REMOVED`). Every problem is reported at once, by
key, with what was expected: a typo gets the nearest valid key suggested. Nothing here does
I/O except :func:`load_fusion_settings`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import types
import typing
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from skelfuse.fusion.settings import FusionSettings


class FusionConfigError(ValueError):
    """The fusion configuration is unusable; the message lists every problem."""


RENAMED: dict[str, str] = {
    "association_gate_m": "tracking.gate_m",
    "track_timeout_s": "tracking.timeout_s",
    "track_min_frames": "tracking.min_frames",
    "state_weights": "weights.state_weights",
    "use_bone_length": "weights.bone_length",
    "bone_length_scale_m": "weights.bone_length_scale_m",
    "use_range_of_motion": "weights.range_of_motion",
    "rom_scale_deg": "weights.rom_scale_deg",
    "use_sensor_priors": "weights.sensor_priors",
    "view_lean_fraction": "weights.view_lean_fraction",
    "use_mirror_correction": "mirror.enabled",
    "mirror_geometry_weight_m": "mirror.geometry_weight_m",
    "mirror_hysteresis_m": "mirror.hysteresis_m",
    "mirror_track_weight": "mirror.track_weight",
    "mirror_anatomy_weight_m": "mirror.anatomy_weight_m",
    "mirror_walk_check_s": "mirror.walk_check_s",
    "mirror_walk_min_speed_mps": "mirror.walk_min_speed_mps",
    "mirror_redecide": "mirror.redecide",
    "mirror_redecide_evidence": "mirror.redecide_evidence",
    "mirror_redecide_tau_s": "mirror.redecide_tau_s",
    "mirror_redecide_young_s": "mirror.redecide_young_s",
    "mirror_redecide_views": "mirror.redecide_views",
    "mirror_unbiased_facing": "mirror.unbiased_facing",
    "filter": "smoothing.filter",
    "one_euro_min_cutoff_hz": "smoothing.one_euro_min_cutoff_hz",
    "one_euro_beta": "smoothing.one_euro_beta",
    "one_euro_d_cutoff_hz": "smoothing.one_euro_d_cutoff_hz",
    "kalman_accel_std": "smoothing.kalman_accel_std",
    "kalman_meas_std_m": "smoothing.kalman_meas_std_m",
    "kalman_predict_s": "smoothing.kalman_predict_s",
    "kalman_ca_jerk_std": "smoothing.kalman_ca_jerk_std",
    "kalman_ca_meas_std_m": "smoothing.kalman_ca_meas_std_m",
    "kalman_ca_accel_tau_s": "smoothing.kalman_ca_accel_tau_s",
    "kalman_ca_predict_s": "smoothing.kalman_ca_predict_s",
    "kalman_ca_jerk_per_speed": "smoothing.kalman_ca_jerk_per_speed",
    "bone_estimate_window": "bones.window",
    "bone_estimate_min_samples": "bones.min_samples",
    "bone_estimate_symmetric": "bones.symmetric",
    "bone_estimate_lock_samples": "bones.lock_samples",
    "enforce_bone_lengths": "bones.enforce",
    "bone_fit_iterations": "bones.fit_iterations",
    "drift_detection": "drift.enabled",
    "drift_window_s": "drift.window_s",
    "drift_check_interval_s": "drift.check_interval_s",
    "drift_threshold_deg": "drift.threshold_deg",
    "drift_threshold_mm": "drift.threshold_mm",
    "drift_confirm_checks": "drift.confirm_checks",
    "alignment": "alignment.policy",
    "alignment_deadline_s": "alignment.deadline_s",
    "alignment_max_extrapolation_s": "alignment.max_extrapolation_s",
    "alignment_predictor": "alignment.predictor",
    "alignment_predict_acceleration": "alignment.predict_acceleration",
    "alignment_grid": "alignment.grid",
    "alignment_skip_expected_late": "alignment.skip_expected_late",
    "alignment_wait_for_phase": "alignment.wait_for_phase",
    "alignment_jitter_fallback_s": "alignment.jitter_fallback_s",
    "alignment_deadline_grace_s": "alignment.deadline_grace_s",
}
"""Each flat key of before (a ``FusionSettings`` field until the groups) -> ``group.key``: read
with a DeprecationWarning, and the record scripts/codemod_settings.py rewrites code by."""

_YAW = "the yaw correction measured worse (a view's own facing is too noisy to turn it by)"
_DISTANCE = "the distance term cost accuracy in the benchmark; far views are often the frontal ones"
_CAUCHY = "the Cauchy re-weighting pass was off by default and no benchmark showed it helping"
_LEARNED = (
    "each sensor's error is learned from the rig ([fusion.learning]); its type's prior is "
    "in fusion/priors.py"
)
_LEARNED_KEYS = ("facing_power", "facing_floor", "facing_back_factor", "view_error_m",
                 "view_jitter_per_m2", "view_occlusion_m")  # fmt: skip
REMOVED: dict[str, str] = {
    **dict.fromkeys(("use_facing", "use_view_reliability", *_LEARNED_KEYS), _LEARNED),
    **dict.fromkeys(("weights.facing", "weights.view_reliability"), _LEARNED),
    **dict.fromkeys((f"weights.{key}" for key in _LEARNED_KEYS), _LEARNED),
    "correct_view_yaw": _YAW,
    "yaw_max_deg": _YAW,
    "use_distance": _DISTANCE,
    "distance_best_m": _DISTANCE,
    "distance_scale_m": _DISTANCE,
    "outlier_scale_m": _CAUCHY,
    "bone_length_fit": "only 'projection' is left: the benchmark showed 'chain' costing accuracy",
}
"""Each flat key whose setting was removed -> why, in one line (the loader's message)."""

_GROUPS: dict[str, type] = {
    f.name: typing.get_type_hints(FusionSettings)[f.name]
    for f in dataclasses.fields(FusionSettings)
}
_HINTS: dict[str, dict[str, Any]] = {
    group: typing.get_type_hints(cls) for group, cls in _GROUPS.items()
}
_DOTTED: tuple[str, ...] = tuple(f"{g}.{k}" for g, hints in _HINTS.items() for k in hints)


def _number(value: object) -> float | None:
    """``value`` as a finite float if it is an int or float (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def _check(name: str, hint: Any, value: object) -> tuple[object, str | None]:
    """Converts ``value`` for the field; returns (converted, problem or None)."""
    origin = typing.get_origin(hint)
    if origin is typing.Literal:
        choices = typing.get_args(hint)
        if value in choices:
            return value, None
        return value, f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}"
    if origin in (typing.Union, types.UnionType):  # int | None: TOML has no null, omit the key
        (inner,) = [arg for arg in typing.get_args(hint) if arg is not type(None)]
        return _check(name, inner, value)
    if origin is tuple:
        items = typing.get_args(hint)
        if not isinstance(value, list) or len(value) != len(items):
            return value, f"{name}: expected a list of {len(items)} numbers, got {value!r}"
        numbers = [_number(v) for v in value]
        if any(n is None or n < 0 for n in numbers):
            return value, f"{name}: expected {len(items)} finite numbers ≥ 0, got {value!r}"
        return tuple(numbers), None
    if hint is bool:
        if isinstance(value, bool):
            return value, None
        return value, f"{name}: expected true or false, got {value!r}"
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
            return value, None
        return value, f"{name}: expected a whole number ≥ 0, got {value!r}"
    if hint is float:
        number = _number(value)
        if number is not None and number >= 0:
            return number, None
        return value, f"{name}: expected a finite number ≥ 0, got {value!r}"
    raise TypeError(f"FusionSettings.{name}: unsupported type {hint!r}")  # a programming error


def _unknown(name: str, group: str | None) -> str:
    """The problem of an unknown key, with the nearest valid one: in its group, else any."""
    leaf = name.rsplit(".", 1)[-1]
    close: list[str] = []
    if group is not None:
        close = [f"{group}.{k}" for k in difflib.get_close_matches(leaf, list(_HINTS[group]), n=1)]
    if not close:
        by_leaf = {dotted.rsplit(".", 1)[-1]: dotted for dotted in _DOTTED}
        by_leaf |= {group_name: group_name for group_name in _GROUPS}
        close = [by_leaf[k] for k in difflib.get_close_matches(leaf, list(by_leaf), n=1)]
        close = close or difflib.get_close_matches(name, _DOTTED, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return f"{name}: not a fusion setting{hint}"


def _regroup(table: Mapping[str, object], problems: list[str]) -> dict[str, dict[str, object]]:
    """``table``'s values by group and key, the flat keys of before moved to their group (with
    one DeprecationWarning for them all); the keys that fit nowhere go to ``problems``."""
    grouped: dict[str, dict[str, object]] = {}
    moved: list[str] = []
    for key, value in table.items():
        if key in _GROUPS and isinstance(value, Mapping):
            for inner, inner_value in value.items():
                grouped.setdefault(key, {})[str(inner)] = inner_value
        elif key in _GROUPS and key not in RENAMED:
            problems.append(f"{key}: expected a table ([fusion.{key}]), got {value!r}")
        elif key in REMOVED:
            problems.append(f"{key}: removed: {REMOVED[key]}")
        elif key in RENAMED:
            group, inner = RENAMED[key].split(".")
            if inner in grouped.get(group, {}) or inner in _table_of(table, group):
                problems.append(f"{key}: given twice, also as {group}.{inner}")
                continue
            grouped.setdefault(group, {})[inner] = value
            moved.append(f"{key} -> {group}.{inner}")
        else:
            problems.append(_unknown(key, None))
    if moved:
        warnings.warn(
            "fusion settings: flat keys are deprecated, write them in their group's table "
            f"([fusion.<group>] <key>): {', '.join(moved)}",
            DeprecationWarning,
            stacklevel=3,
        )
    return grouped


def _table_of(table: Mapping[str, object], group: str) -> Mapping[str, object]:
    """``table[group]`` if it is a table, else an empty one."""
    inner = table.get(group)
    return inner if isinstance(inner, Mapping) else {}


def fusion_settings_from_mapping(
    table: Mapping[str, object], base: FusionSettings | None = None
) -> FusionSettings:
    """``base`` (default: the defaults) with the given fields replaced.

    Args:
        table: ``{group: {key: value}}`` as a TOML ``[fusion]`` table reads (flat keys of before
            accepted, with a DeprecationWarning).

    Raises:
        FusionConfigError: on unknown or removed keys or values of the wrong type or range, all
            listed.
    """
    problems: list[str] = []
    changes: dict[str, dict[str, object]] = {}
    for group, values in _regroup(table, problems).items():
        for key, value in values.items():
            name = f"{group}.{key}"
            if name in REMOVED:
                problems.append(f"{name}: removed: {REMOVED[name]}")
                continue
            if key not in _HINTS[group]:
                problems.append(_unknown(name, group))
                continue
            converted, problem = _check(name, _HINTS[group][key], value)
            if problem:
                problems.append(problem)
            else:
                changes.setdefault(group, {})[key] = converted
    weights = changes.get("weights", {}).get("state_weights")
    if isinstance(weights, tuple) and any(w > 1 for w in weights):
        problems.append(
            f"weights.state_weights: each weight must be in [0, 1], got {list(weights)}"
        )
    problems += _alignment_problems(changes.get("alignment", {}))
    if problems:
        raise FusionConfigError("; ".join(problems))
    base = base or FusionSettings()
    groups = {g: dataclasses.replace(getattr(base, g), **kv) for g, kv in changes.items()}
    return dataclasses.replace(base, **groups)


MAX_ALIGNMENT_S = 0.1
"""The alignment bounds' upper limit (seconds): the hub's ``max_wait_s``; a deadline later than
that never fires, and beyond it a sensor's motion is no longer a straight line."""


def _alignment_problems(changes: Mapping[str, object]) -> list[str]:
    """The alignment bounds (fusion/alignment.py) out of range: the deadline in (0, 0.1]
    seconds, the extrapolation in [0, 0.1] (0: a late sensor is always left out), the jitter
    fallback and the deadline's grace in [0, 0.1] (0: never)."""
    problems = []
    deadline = changes.get("deadline_s")
    if isinstance(deadline, float) and not 0.0 < deadline <= MAX_ALIGNMENT_S:
        problems.append(
            f"alignment.deadline_s: expected seconds in (0, {MAX_ALIGNMENT_S}], got {deadline!r}"
        )
    for name in ("max_extrapolation_s", "jitter_fallback_s", "deadline_grace_s"):
        bound = changes.get(name)
        if isinstance(bound, float) and bound > MAX_ALIGNMENT_S:
            problems.append(
                f"alignment.{name}: expected seconds in [0, {MAX_ALIGNMENT_S}], got {bound!r}"
            )
    return problems


def read_toml(path: Path, error: type[Exception]) -> dict[str, Any]:
    """The TOML document at ``path`` (a deployment's settings file: fusion, outputs).

    Raises:
        error: the file is unreadable or not TOML; the message starts with the path.
    """
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise error(f"{path}: cannot read it ({exc.strerror or exc})") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not valid TOML ({exc})") from exc


def load_fusion_settings(path: str | Path) -> FusionSettings:
    """Fusion settings from the ``[fusion]`` table (and its ``[fusion.<group>]`` tables) of a
    TOML file.

    Raises:
        FusionConfigError: the file is missing, unreadable, not TOML, has other tables, or has
            bad settings; the message starts with the path.
    """
    path = Path(path)
    document = read_toml(path, FusionConfigError)
    others = sorted(set(document) - {"fusion"})
    if others:
        raise FusionConfigError(
            f"{path}: only a [fusion] table is read here; also found {', '.join(others)}"
        )
    table = document.get("fusion", {})
    if not isinstance(table, dict):
        raise FusionConfigError(f"{path}: 'fusion' must be a table ([fusion])")
    try:
        return fusion_settings_from_mapping(table)
    except FusionConfigError as exc:
        raise FusionConfigError(f"{path}: {exc}") from exc


def fusion_settings_as_dict(settings: FusionSettings) -> dict[str, dict[str, object]]:
    """Every field by group and name, JSON-ready (tuples as lists): the TOML file's shape."""
    out: dict[str, dict[str, object]] = {}
    for group in _GROUPS:
        values = getattr(settings, group)
        out[group] = {}
        for name in _HINTS[group]:
            value = getattr(values, name)
            out[group][name] = list(value) if isinstance(value, tuple) else value
    return out
