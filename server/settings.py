"""Server settings: one frozen object built once (CLI or tests) and passed in, never global."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from skelfuse.fusion.settings import FusionSettings, HubSettings
from skelfuse.protocol.constants import DEFAULT_HTTP_PORT, DEFAULT_ZMQ_PORT

__all__ = ["FusionSettings", "HubSettings", "OutputSpec", "Settings"]


@dataclass(frozen=True, slots=True)
class OutputSpec:
    """One output of fused frames besides the WebSocket feed (docs/outputs.md)."""

    kind: Literal["osc", "vmc", "lsl", "nats"]
    host: str = "127.0.0.1"
    port: int = 0
    """UDP port of the receiver (osc, vmc), the NATS server's client port (nats); unused by
    lsl."""
    rotations: bool = False
    """osc: add each joint's rotation (``/rot``)."""
    slots: int = 6
    """lsl: persons per sample."""
    queue: int = 8
    """Frames waiting for the output's thread; beyond them frames are dropped (counted)."""
    room: str = "default"
    """nats: the room's subject token (``skelfuse.<room>.frames``)."""
    jetstream: bool = False
    """nats: keep a replayable history in a JetStream stream (``history_s``, ``history_msgs``)."""
    history_s: int = 10
    """nats with jetstream: seconds of frames kept."""
    history_msgs: int = 0
    """nats with jetstream: at most this many frames kept (0: no limit but ``history_s``)."""


@dataclass(frozen=True, slots=True)
class Settings(HubSettings):
    """The server's settings: the hub's (fusion, output grid, liveness) and the network's."""

    http_host: str = "127.0.0.1"
    http_port: int = DEFAULT_HTTP_PORT
    zmq_endpoint: str = f"tcp://*:{DEFAULT_ZMQ_PORT}"
    data_dir: Path = Path("skelfuse-data")
    ws_send_timeout_s: float = 5.0
    """A WebSocket client that has not taken a frame for this long (the newest waiting in its
    one-frame mailbox), or whose greeting takes this long, is closed with 1008 and counted."""
    api_token: str | None = None
    """When set, REST mutations and reads of people's data (``security.needs_token``) need
    ``Authorization: Bearer <token>`` and the WebSocket needs ``?token=<token>``; status reads
    (health, sensors, calibration, metrics) stay open."""
    allowed_origins: tuple[str, ...] = ()
    """Browser origins (``http://host:port``) allowed on the WebSocket besides the server's own."""
    max_body_bytes: int = 1024 * 1024
    """Larger HTTP request bodies are refused with 413 before they are read."""
    curve: bool = False
    """Authenticate agents with CurveZMQ (keys under ``<data_dir>/keys``, see docs/security.md)."""
    outputs: tuple[OutputSpec, ...] = ()
    """OSC, VMC and LSL outputs (``--osc``, ``--vmc``, ``--lsl``; docs/outputs.md)."""
