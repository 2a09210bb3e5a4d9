"""Outputs from a deployment's TOML file (``skelfuse server --outputs-config FILE``), validated
once at this trust boundary; docs/outputs.md. One ``[[outputs]]`` table per output::

    [[outputs]]
    kind = "osc"            # osc | vmc | lsl
    host = "192.168.1.20"
    port = 9000
    rotations = true        # osc: each joint's rotation too

    [[outputs]]
    kind = "lsl"
    slots = 4               # persons per sample
"""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Literal, TypeVar, cast

from skelfuse.server.settings import OutputSpec

VMC_PORT = 39539
"""Where VMC "Marionettes" (the avatar apps) listen by default (protocol.vmc.info)."""
Kind = Literal["osc", "vmc", "lsl"]
_KINDS = ("osc", "vmc", "lsl")
_T = TypeVar("_T", str, int, bool)
_FIELDS = {f.name for f in dataclasses.fields(OutputSpec)}


class OutputConfigError(ValueError):
    """The outputs configuration is unusable; the message says where and why."""


def output_from_mapping(table: Mapping[str, object], where: str = "outputs") -> OutputSpec:
    """One output's table → :class:`OutputSpec`.

    Raises:
        OutputConfigError: an unknown key or kind, a value of the wrong type, a port outside
            1..65535 (osc needs one; vmc defaults to 39539), a slot or queue count below 1.
    """
    unknown = sorted(set(table) - _FIELDS)
    if unknown:
        raise OutputConfigError(f"{where}: unknown keys {', '.join(unknown)}")
    kind = table.get("kind")
    if kind not in _KINDS:
        raise OutputConfigError(f"{where}: kind must be one of {', '.join(_KINDS)}, got {kind!r}")
    host = _typed(table, "host", "127.0.0.1", where)
    port = _typed(table, "port", VMC_PORT if kind == "vmc" else 0, where)
    rotations = _typed(table, "rotations", False, where)
    slots = _typed(table, "slots", 6, where)
    queue = _typed(table, "queue", 8, where)
    if kind != "lsl" and not 0 < port < 65536:
        raise OutputConfigError(f"{where}: {kind} needs a port in 1..65535")
    if slots < 1 or queue < 1:
        raise OutputConfigError(f"{where}: slots and queue must be at least 1")
    return OutputSpec(cast(Kind, kind), host, port, rotations, slots, queue)


def _typed(table: Mapping[str, object], key: str, default: _T, where: str) -> _T:
    """``table[key]`` if of ``default``'s type (a bool is not an int here), else ``default``
    when absent.

    Raises:
        OutputConfigError: present with another type.
    """
    value = table.get(key, default)
    if type(value) is not type(default):
        raise OutputConfigError(f"{where}: {key} must be a {type(default).__name__}")
    return value


def load_outputs(path: str | Path) -> tuple[OutputSpec, ...]:
    """The ``[[outputs]]`` tables of a TOML file.

    Raises:
        OutputConfigError: the file is unreadable, not TOML, has other keys, or a bad output;
            the message starts with the path.
    """
    path = Path(path)
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise OutputConfigError(f"{path}: cannot read it ({exc.strerror or exc})") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise OutputConfigError(f"{path}: not valid TOML ({exc})") from exc
    others = sorted(set(document) - {"outputs"})
    tables = document.get("outputs", [])
    if others or not isinstance(tables, list):
        raise OutputConfigError(f"{path}: expected only [[outputs]] tables")
    return tuple(
        output_from_mapping(table, f"{path}: outputs[{k}]") for k, table in enumerate(tables)
    )
