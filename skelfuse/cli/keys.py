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
    """Create keys (and say where to copy them), or list them; 1 when there are none to list.

    Raises:
        UsageError: the keys cannot be created (the message says why).
    """
    from skelfuse.server.auth import (
        KeysMissing,
        allowed_agents,
        create_agent_keys,
        create_server_keys,
        key_paths,
    )

    data = Path(args.data)
    paths = key_paths(data)
    if args.action == "create":
        try:
            create_server_keys(data)
            made = [create_agent_keys(data, sensor_id) for sensor_id in args.agent]
        except KeysMissing as exc:
            raise UsageError(str(exc)) from exc
        print(f"server key pair: {paths.server_secret} (public: {paths.server_public})")
        for path in made:
            print(f"agent {path.stem}: copy {path} and {paths.server_public} to its PC, then run")
            print(f"  skelfuse agent --id {path.stem} --key {path.name} --server-key server.key")
        print("start the server with --curve (restart it after adding or removing agents)")
        return 0
    if not paths.server_public.exists():
        print(f"no keys in {paths.root} (create them with 'skelfuse keys create')")
        return 1
    print(f"server public key: {paths.server_public}")
    for public, sensor_id in sorted(allowed_agents(data).items(), key=lambda kv: kv[1]):
        print(f"  {sensor_id:<24} {public}")
    return 0
