"""Outputs from a deployment's TOML file (``skelfuse server --outputs-config FILE``), validated
once at this trust boundary; docs/outputs.md. One ``[[outputs]]`` table per output::

    [[outputs]]
    kind = "osc"            # osc | vmc | lsl | nats
    host = "192.168.1.20"
    port = 9000
    rotations = true        # osc: each joint's rotation too

    [[outputs]]
    kind = "lsl"
    slots = 4               # persons per sample

    [[outputs]]
    kind = "nats"
    host = "127.0.0.1"      # port 4222 unless given
    room = "hall-a"         # subject skelfuse.hall-a.frames
    jetstream = true        # keep history_s (default 10) seconds for late subscribers
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Literal, TypeVar, cast

from skelfuse.fusion.config import read_toml
from skelfuse.server.output_nats import NATS_PORT, room_subject
from skelfuse.server.settings import OutputSpec

VMC_PORT = 39539
"""Where VMC "Marionettes" (the avatar apps) listen by default (protocol.vmc.info)."""
Kind = Literal["osc", "vmc", "lsl", "nats"]
_KINDS = ("osc", "vmc", "lsl", "nats")
_DEFAULT_PORTS = {"vmc": VMC_PORT, "nats": NATS_PORT}
_T = TypeVar("_T", str, int, bool)
_FIELDS = {f.name for f in dataclasses.fields(OutputSpec)}


class OutputConfigError(ValueError):
    """The outputs configuration is unusable; the message says where and why."""


def output_from_mapping(table: Mapping[str, object], where: str = "outputs") -> OutputSpec:
    """One output's table → :class:`OutputSpec`.

    Raises:
        OutputConfigError: an unknown key or kind, a value of the wrong type, a port outside
            1..65535 (osc needs one; vmc defaults to 39539, nats to 4222), a slot or queue count
            below 1, a nats room that is not one subject token, negative history.
    """
    unknown = sorted(set(table) - _FIELDS)
    if unknown:
        raise OutputConfigError(f"{where}: unknown keys {', '.join(unknown)}")
    kind = table.get("kind")
    if kind not in _KINDS:
        raise OutputConfigError(f"{where}: kind must be one of {', '.join(_KINDS)}, got {kind!r}")
    host = _typed(table, "host", "127.0.0.1", where)
    port = _typed(table, "port", _DEFAULT_PORTS.get(str(kind), 0), where)
    rotations = _typed(table, "rotations", False, where)
    slots = _typed(table, "slots", 6, where)
    queue = _typed(table, "queue", 8, where)
    if kind != "lsl" and not 0 < port < 65536:
        raise OutputConfigError(f"{where}: {kind} needs a port in 1..65535")
    if slots < 1 or queue < 1:
        raise OutputConfigError(f"{where}: slots and queue must be at least 1")
    room = _typed(table, "room", "default", where)
    try:
        room_subject(room)
    except ValueError as exc:
        raise OutputConfigError(f"{where}: {exc}") from exc
    jetstream = _typed(table, "jetstream", False, where)
    history_s = _typed(table, "history_s", 10, where)
    history_msgs = _typed(table, "history_msgs", 0, where)
    if history_s < 1 or history_msgs < 0:
        raise OutputConfigError(f"{where}: history_s must be at least 1, history_msgs at least 0")
    return OutputSpec(
        cast(Kind, kind),
        host,
        port,
        rotations,
        slots,
        queue,
        room,
        jetstream,
        history_s,
        history_msgs,
    )


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
    document = read_toml(path, OutputConfigError)
    others = sorted(set(document) - {"outputs"})
    tables = document.get("outputs", [])
    if others or not isinstance(tables, list):
        raise OutputConfigError(f"{path}: expected only [[outputs]] tables")
    return tuple(
        output_from_mapping(table, f"{path}: outputs[{k}]") for k, table in enumerate(tables)
    )
