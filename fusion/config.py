"""Fusion settings from a deployment's TOML file, validated once at this trust boundary.

A file holds one ``[fusion]`` table whose keys are :class:`~server.settings.FusionSettings`
fields (docs/fusion.md §9); what it leaves out keeps its default::

    [fusion]
    filter = "kalman"          # kalman_ca (default) | one_euro | kalman | none
    mirror_walk_check_s = 0    # dance: people walk backwards on purpose
    use_distance = true

Every problem is reported at once, by key, with what was expected: a typo gets the nearest
valid key suggested. Nothing here does I/O except :func:`load_fusion_settings`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from skelfuse.fusion.settings import FusionSettings


class FusionConfigError(ValueError):
    """The fusion configuration is unusable; the message lists every problem."""


_HINTS: dict[str, Any] = typing.get_type_hints(FusionSettings)
_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(FusionSettings))


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


def fusion_settings_from_mapping(
    table: Mapping[str, object], base: FusionSettings | None = None
) -> FusionSettings:
    """``base`` (default: the defaults) with the given fields replaced.

    Raises:
        FusionConfigError: on unknown keys or values of the wrong type or range, all listed.
    """
    problems: list[str] = []
    changes: dict[str, object] = {}
    for key, value in table.items():
        if key not in _HINTS:
            close = difflib.get_close_matches(key, _FIELDS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            problems.append(f"{key}: not a fusion setting{hint}")
            continue
        converted, problem = _check(key, _HINTS[key], value)
        if problem:
            problems.append(problem)
        else:
            changes[key] = converted
    weights = changes.get("state_weights")
    if isinstance(weights, tuple) and any(w > 1 for w in weights):
        problems.append(f"state_weights: each weight must be in [0, 1], got {list(weights)}")
    problems += _alignment_problems(changes)
    if problems:
        raise FusionConfigError("; ".join(problems))
    return dataclasses.replace(base or FusionSettings(), **changes)  # type: ignore[arg-type]


MAX_ALIGNMENT_S = 0.1
"""The alignment bounds' upper limit (seconds): the hub's ``max_wait_s``; a deadline later than
that never fires, and beyond it a sensor's motion is no longer a straight line."""


def _alignment_problems(changes: Mapping[str, object]) -> list[str]:
    """The alignment bounds (fusion/alignment.py) out of range: the deadline in (0, 0.1]
    seconds, the extrapolation in [0, 0.1] (0: a late sensor is always left out), the jitter
    fallback and the deadline's grace in [0, 0.1] (0: never)."""
    problems = []
    deadline = changes.get("alignment_deadline_s")
    if isinstance(deadline, float) and not 0.0 < deadline <= MAX_ALIGNMENT_S:
        problems.append(
            f"alignment_deadline_s: expected seconds in (0, {MAX_ALIGNMENT_S}], got {deadline!r}"
        )
    for name in (
        "alignment_max_extrapolation_s",
        "alignment_jitter_fallback_s",
        "alignment_deadline_grace_s",
    ):
        bound = changes.get(name)
        if isinstance(bound, float) and bound > MAX_ALIGNMENT_S:
            problems.append(f"{name}: expected seconds in [0, {MAX_ALIGNMENT_S}], got {bound!r}")
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
    """Fusion settings from the ``[fusion]`` table of a TOML file.

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


def fusion_settings_as_dict(settings: FusionSettings) -> dict[str, object]:
    """Every field by name, JSON-ready (tuples as lists)."""
    out: dict[str, object] = {}
    for name in _FIELDS:
        value = getattr(settings, name)
        out[name] = list(value) if isinstance(value, tuple) else value
    return out
