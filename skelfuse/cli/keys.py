"""``skelfuse keys``: create and list the CurveZMQ key pairs of the server and its agents."""

from __future__ import annotations

import argparse
from pathlib import Path

from skelfuse.cli.values import UsageError


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``keys create|list`` to the command line."""
    keys = sub.add_parser("keys", help="create and list CurveZMQ keys for the server and agents")
    keys.add_argument("action", choices=["create", "list"])
    keys.add_argument("--data", default="skelfuse-data", help="the server's data folder")
    keys.add_argument(
        "--agent",
        action="append",
        default=[],
        metavar="SENSOR_ID",
        help="create: a key pair for this sensor id (repeatable)",
    )
    keys.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Create the missing keys (and say where to copy them), or list them.

    ``create`` again with the whole list of sensors keeps the keys that exist and adds the
    missing ones; it returns 1 when a sensor's keys are inconsistent (each one said why), the
    others are still done. ``list`` returns 1 when there are no keys.

    Raises:
        UsageError: an invalid sensor id (nothing is created then).
    """
    from skelfuse.server.auth import allowed_agents, key_paths

    data = Path(args.data)
    paths = key_paths(data)
    if args.action == "create":
        return _create(data, list(dict.fromkeys(args.agent)))
    if not paths.server_public.exists():
        print(f"no keys in {paths.root} (create them with 'skelfuse keys create')")
        return 1
    print(f"server public key: {paths.server_public}")
    for public, sensor_id in sorted(allowed_agents(data).items(), key=lambda kv: kv[1]):
        print(f"  {sensor_id:<24} {public}")
    return 0


def _create(data: Path, sensor_ids: list[str]) -> int:
    """``keys create``: the server's pair and one per sensor id, each made only if missing.

    Raises:
        UsageError: an invalid sensor id (checked before anything is written).
    """
    from skelfuse.protocol.wire import SENSOR_ID_PATTERN
    from skelfuse.server.auth import KeysMissing, create_agent_keys, create_server_keys, key_paths

    invalid = [s for s in sensor_ids if not SENSOR_ID_PATTERN.fullmatch(s)]
    if invalid:
        raise UsageError(
            f"not a valid sensor id (A-Z a-z 0-9 . _ -, ≤ 64): {', '.join(map(repr, invalid))}"
        )
    paths = key_paths(data)
    existed = paths.server_secret.exists()
    create_server_keys(data)
    print(
        f"server key pair: {paths.server_secret} (public: {paths.server_public})"
        + (" - kept" if existed else " - created")
    )
    failed = 0
    created = 0
    for sensor_id in sensor_ids:
        try:
            key = create_agent_keys(data, sensor_id)
        except KeysMissing as exc:
            print(f"agent {sensor_id}: NOT DONE: {exc}")
            failed += 1
            continue
        if not key.created:
            where = key.secret if key.secret.exists() else "no longer here (on its PC?)"
            print(f"agent {sensor_id}: kept its allowlisted key (secret key: {where})")
            continue
        created += 1
        print(f"agent {sensor_id}: created; copy {key.secret} and {paths.server_public} to its PC,")
        print(f"  then run: skelfuse agent --id {sensor_id} --key {key.secret.name} "
              "--server-key server.key")  # fmt: skip
    if created:
        print("start the server with --curve (restart it after adding or removing agents)")
    return 1 if failed else 0
