"""Constants shared by agents and the server (zguide Paranoid Pirate naming)."""

from __future__ import annotations

from typing import Final

PROTOCOL_VERSION: Final = 1
DEFAULT_ZMQ_PORT: Final = 5555
DEFAULT_HTTP_PORT: Final = 8000

HEARTBEAT_INTERVAL_S: Final = 1.0
"""Both sides send a heartbeat when they have sent nothing else for this long."""
HEARTBEAT_LIVENESS: Final = 3
"""A peer silent for this many heartbeat intervals is considered gone."""

MAX_BODIES: Final = 6
"""Kinect v2 and k4abt both track at most six bodies."""
MAX_MESSAGE_BYTES: Final = 64 * 1024
"""Six bodies of 25 joints are about 2.5 KB; anything near this limit is garbage."""
MAX_RESPONSE_BYTES: Final = 4 * 1024 * 1024
"""Limit for an agent's answer to a request the server made (a depth point cloud is ~250 KB);
the server allows it only from a sensor it is waiting on."""
MAX_COORDINATE_M: Final = 50.0
"""A joint farther than this from its sensor is not a measurement."""

AGENT_SEND_HWM: Final = 30
"""At most one second of frames queued on an agent: a reconnect never flushes a stale backlog."""

MOVING_SENSORS: Final = "moving_sensors"
"""The ``welcome`` feature (docs/protocol.md §6.2) of a server that poses a moving sensor's frames
by their ``pose`` and its ``hello``'s ``pose_space``; agents of moving sensors wait for it."""
