"""``skelfuse keys create`` run again with the whole list of sensors (issue 13 item 5).

Run through the command line's ``main`` in this process, as a user types it. It failed the second
time with a raw "No such file or directory" (the public key file it copied had been moved away
by the first run).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import zmq.auth

from skelfuse.cli import main
from skelfuse.server.auth import allowed_agents, key_paths


def _create(data: Path, *agents: str) -> int:
    return main(["keys", "create", "--data", str(data), *(f"--agent={a}" for a in agents)])


def _public_and_secret(path: Path) -> tuple[bytes, bytes | None]:
    public, secret = zmq.auth.load_certificate(path)
    return bytes(public), secret


def test_create_again_with_the_full_list_adds_the_missing_keys_and_keeps_the_others(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    paths = key_paths(tmp_path)
    assert _create(tmp_path, "front", "back") == 0
    first = capsys.readouterr().out
    assert "server key pair" in first and "created" in first
    server_before = paths.server_secret.read_bytes()
    front_before = _public_and_secret(paths.agent_secret("front"))
    allowed_before = allowed_agents(tmp_path)

    assert _create(tmp_path, "front", "back", "side") == 0
    second = capsys.readouterr().out
    assert "No such file" not in second
    assert "server key pair" in second and "kept" in second, second
    assert "agent front: kept" in second and "agent back: kept" in second, second
    assert "agent side: created" in second, second
    # Nothing existing was replaced; the new sensor is allowlisted beside the others.
    assert paths.server_secret.read_bytes() == server_before
    assert _public_and_secret(paths.agent_secret("front")) == front_before
    allowed = allowed_agents(tmp_path)
    assert {k: v for k, v in allowed.items() if v != "side"} == allowed_before
    assert sorted(allowed.values()) == ["back", "front", "side"]
    side_public, _ = _public_and_secret(paths.agent_secret("side"))
    assert allowed[side_public.decode()] == "side"

    # A third time changes nothing at all.
    assert _create(tmp_path, "front", "back", "side") == 0
    assert allowed_agents(tmp_path) == allowed


def test_a_revoked_or_mismatched_key_is_reported_never_replaced(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    paths = key_paths(tmp_path)
    assert _create(tmp_path, "front", "back") == 0
    capsys.readouterr()
    back_secret = paths.agent_secret("back").read_bytes()
    (paths.agents / "back.key").unlink()  # revoked, as docs/security.md says
    # front's allowlisted key is replaced by another pair's public key (a mix-up)
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    zmq.auth.create_certificates(str(stranger), "front")
    (paths.agents / "front.key").write_bytes((stranger / "front.key").read_bytes())

    assert _create(tmp_path, "front", "back", "side") == 1
    out = capsys.readouterr().out
    assert "agent side: created" in out, out  # the others are still done
    assert "front" in out and "is not the public key of" in out, out
    assert "back" in out and "not allowlisted" in out and "delete" in out, out
    # Neither was touched: the revoked key stays revoked, the secret stays as it was.
    assert not (paths.agents / "back.key").exists()
    assert paths.agent_secret("back").read_bytes() == back_secret
    assert (paths.agents / "front.key").read_bytes() == (stranger / "front.key").read_bytes()

    # Deleting the old secret, as the message says, gives the sensor a new pair.
    paths.agent_secret("back").unlink()
    assert _create(tmp_path, "back") == 0
    assert paths.agent_secret("back").read_bytes() != back_secret
    assert "back" in allowed_agents(tmp_path).values()


def test_an_invalid_sensor_id_creates_nothing(tmp_path: Path) -> None:
    assert _create(tmp_path, "front", "not valid") == 2
    assert not key_paths(tmp_path).root.exists()
