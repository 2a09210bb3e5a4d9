"""Agent authentication with CurveZMQ ("Ironhouse": both sides have keys, the server allowlists).

Key layout under ``<data>/keys`` (made by ``skelfuse keys create``)::

    server.key, server.key_secret        the server's key pair (server.key is public)
    agents/<sensor_id>.key               allowlist: one public key per sensor id
    agent-secrets/<sensor_id>.key_secret an agent's key pair, to copy to that sensor's PC

The server fails closed: with ``curve`` on it refuses to start without its keys, every
connection is authenticated by a ZAP handler with ``ZAP_ENFORCE_DOMAIN`` set (libzmq otherwise
accepts any client when no handler answers), and the authenticated key's file name is the only
sensor id that connection may register (``key_mismatch`` otherwise). Revoking a sensor =
deleting its ``agents/<id>.key`` and restarting the server.
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.asyncio
import zmq.auth
from zmq.auth.asyncio import AsyncioAuthenticator
from zmq.utils import z85

from skelfuse.protocol.wire import SENSOR_ID_PATTERN

logger = logging.getLogger(__name__)
ZAP_DOMAIN = "skelfuse"


class KeysMissing(Exception):
    """Keys are missing or unusable; the message says which command fixes it."""


@dataclass(frozen=True, slots=True)
class KeyPaths:
    root: Path

    @property
    def server_public(self) -> Path:
        return self.root / "server.key"

    @property
    def server_secret(self) -> Path:
        return self.root / "server.key_secret"

    @property
    def agents(self) -> Path:
        return self.root / "agents"

    @property
    def agent_secrets(self) -> Path:
        return self.root / "agent-secrets"

    def agent_secret(self, sensor_id: str) -> Path:
        return self.agent_secrets / f"{sensor_id}.key_secret"


def key_paths(data_dir: Path) -> KeyPaths:
    return KeyPaths(Path(data_dir) / "keys")


def _create_pair(directory: Path, name: str) -> None:
    """Write ``name.key`` and ``name.key_secret`` into ``directory`` (never half-written)."""
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        zmq.auth.create_certificates(tmp, name)
        for suffix in (".key", ".key_secret"):
            (Path(tmp) / f"{name}{suffix}").replace(directory / f"{name}{suffix}")
    (directory / f"{name}.key_secret").chmod(0o600)


def create_server_keys(data_dir: Path) -> KeyPaths:
    """Create the server's key pair unless it exists (keys are never silently replaced)."""
    paths = key_paths(data_dir)
    if not paths.server_secret.exists():
        _create_pair(paths.root, "server")
    return paths


@dataclass(frozen=True, slots=True)
class AgentKey:
    """A sensor's key pair after :func:`create_agent_keys`."""

    sensor_id: str
    secret: Path
    """The key pair file to copy to that sensor's PC (may have been moved away already)."""
    created: bool
    """True: made now; False: the sensor's allowlisted key was kept as it was."""


def create_agent_keys(data_dir: Path, sensor_id: str) -> AgentKey:
    """Create a sensor's key pair and allowlist it, or keep the allowlisted one it has.

    Run again with the whole list of sensors, only the missing ones get keys: an existing key is
    never replaced, and a key that was revoked (its secret here, its allowlist entry deleted) is
    not silently allowed again.

    Raises:
        KeysMissing: ``sensor_id`` is not a valid sensor id; its allowlisted public key is not
            the one of its secret key here; or its secret key is here but not allowlisted (the
            message says which file to delete to give it a new key pair).
    """
    if not SENSOR_ID_PATTERN.fullmatch(sensor_id):
        raise KeysMissing(f"{sensor_id!r} is not a valid sensor id (A-Z a-z 0-9 . _ -, ≤ 64)")
    paths = key_paths(data_dir)
    allowlisted = paths.agents / f"{sensor_id}.key"
    secret = paths.agent_secret(sensor_id)
    if allowlisted.exists():
        if secret.exists() and _public_key(secret) != _public_key(allowlisted):
            raise KeysMissing(
                f"{sensor_id}: {allowlisted} is not the public key of {secret}; delete the one "
                "that is wrong (or both, then run this again for a new key pair)"
            )
        return AgentKey(sensor_id, secret, created=False)
    if secret.exists():
        raise KeysMissing(
            f"{sensor_id}: {secret} exists but is not allowlisted in {paths.agents} (revoked?); "
            f"to give {sensor_id} a new key pair, delete {secret} and run this again"
        )
    _create_pair(paths.agent_secrets, sensor_id)
    paths.agents.mkdir(parents=True, exist_ok=True)
    (paths.agent_secrets / f"{sensor_id}.key").replace(allowlisted)  # the same file system
    return AgentKey(sensor_id, secret, created=True)


def _public_key(path: Path) -> bytes:
    public, _ = zmq.auth.load_certificate(path)
    return bytes(public)


def allowed_agents(data_dir: Path) -> dict[str, str]:
    """Allowlisted public keys (z85) → sensor id."""
    paths = key_paths(data_dir)
    allowed: dict[str, str] = {}
    for path in sorted(paths.agents.glob("*.key")) if paths.agents.is_dir() else ():
        public, _ = zmq.auth.load_certificate(path)
        allowed[public.decode()] = path.stem
    return allowed


def server_keys(data_dir: Path) -> tuple[bytes, bytes]:
    paths = key_paths(data_dir)
    if not paths.server_secret.exists():
        raise KeysMissing(
            f"CurveZMQ is on but {paths.server_secret} does not exist: run "
            f"'skelfuse keys create --data {data_dir} --agent <sensor id> ...' first"
        )
    public, secret = zmq.auth.load_certificate(paths.server_secret)
    if secret is None:
        raise KeysMissing(f"{paths.server_secret} has no secret key")
    return public, secret


class SensorAuthenticator(AsyncioAuthenticator):
    """ZAP handler: allowlisted keys only; the User-Id of a connection is its sensor id."""

    def __init__(self, context: zmq.asyncio.Context, data_dir: Path) -> None:
        super().__init__(context)
        self._sensor_of = allowed_agents(data_dir)
        self._location = key_paths(data_dir).agents

    def start(self) -> None:
        super().start()
        self.configure_curve(domain=ZAP_DOMAIN, location=str(self._location))
        logger.info("CurveZMQ on: %d allowlisted agent key(s)", len(self._sensor_of))

    def curve_user_id(self, client_public_key: bytes) -> str:
        z85_key = z85.encode(client_public_key).decode()
        return self._sensor_of.get(z85_key, z85_key)


def secure_router(socket: zmq.asyncio.Socket, data_dir: Path) -> None:
    """Make ``socket`` a CURVE server that only talks to authenticated agents."""
    public, secret = server_keys(data_dir)
    socket.curve_secretkey = secret
    socket.curve_publickey = public
    socket.curve_server = True
    socket.zap_domain = ZAP_DOMAIN.encode()
    socket.setsockopt(zmq.ZAP_ENFORCE_DOMAIN, 1)
