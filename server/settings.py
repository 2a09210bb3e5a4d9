"""Server settings: one frozen object built once (CLI or tests) and passed in, never global."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from protocol.constants import DEFAULT_HTTP_PORT, DEFAULT_ZMQ_PORT, HEARTBEAT_INTERVAL_S


@dataclass(frozen=True, slots=True)
class FusionSettings:
    """Parameters of fusion and tracking (see ``docs/fusion.md``)."""

    state_weights: tuple[float, float, float] = (0.0, 0.3, 0.7)
    """Confidence of a NotTracked / Inferred / Tracked joint (report A's values)."""
    association_gate_m: float = 0.5
    """Views farther apart than this (trunk distance) are never the same person."""
    track_timeout_s: float = 1.0
    """A person unseen by every sensor for this long is gone; a later return gets a new id."""
    track_min_frames: int = 3
    """A new person is published after this many consecutive fused frames (no one-frame ghosts)."""


@dataclass(frozen=True, slots=True)
class Settings:
    http_host: str = "127.0.0.1"
    http_port: int = DEFAULT_HTTP_PORT
    zmq_endpoint: str = f"tcp://*:{DEFAULT_ZMQ_PORT}"
    data_dir: Path = Path("skelfuse-data")
    fusion: FusionSettings = field(default_factory=FusionSettings)
    max_wait_s: float = 0.1
    """Fusion waits at most this long for a late sensor before fusing without it."""
    interpolation_gap_s: float = 0.1
    """Frames further apart than this are not interpolated between (nearest is used)."""
    heartbeat_interval_s: float = HEARTBEAT_INTERVAL_S
    ws_queue_size: int = 2
    """Frames queued per WebSocket client; the oldest is dropped when a client falls behind."""
    ws_send_timeout_s: float = 5.0
    """A client that cannot take one message in this long is disconnected."""
