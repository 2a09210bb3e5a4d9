"""The ``skelfuse`` command line: one module per command group, each adding its subcommand.

``values`` parses command-line values for all of them; the command modules import only it, never
each other. Each command imports the server, recording and fusion inside its ``run``, so an
agent-only install (numpy, pyzmq, msgpack, threadpoolctl) never touches the server's
dependencies. Every command runs with BLAS pinned to one thread (:mod:`skelfuse.blas`), and
ends with the process that started it when that one asks so (:mod:`skelfuse.parent_watch`).
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from skelfuse.blas import pin_blas_threads
from skelfuse.cli import agent, calibration, demo, doctor, keys, mocap, recordings, server
from skelfuse.cli.values import UsageError
from skelfuse.parent_watch import watch_parent_from_environment

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The parser of every subcommand; each sets ``func``, the function that runs it."""
    parser = argparse.ArgumentParser(
        prog="skelfuse",
        description="Markerless multi-sensor motion capture: agents, fusion server, live demo.",
    )
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING (default INFO)")
    sub = parser.add_subparsers(dest="command", required=True)
    server.add_parser(sub)
    agent.add_parser(sub)
    keys.add_parser(sub)
    demo.add_parser(sub)
    recordings.add_parsers(sub)
    calibration.add_parser(sub)
    mocap.add_parser(sub)
    doctor.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``skelfuse ARGS``; the exit status: 2 for a usage error, 1 for an OS error (a port in
    use, a file that cannot be read), 130 on Ctrl-C, else the command's own."""
    args = build_parser().parse_args(argv)
    _configure_logging(args.log_level)
    pin_blas_threads()  # before any command: no busy-waiting BLAS worker takes a core
    watch_parent_from_environment()  # started by the demo: end with it, even if it is killed
    try:
        result: int = args.func(args)
    except UsageError as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    return result


def _configure_logging(level: str) -> None:
    # Imports only logging and re (no server dependency): every command masks secrets.
    from skelfuse.server.log_redaction import RedactSecrets

    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
    for handler in logging.getLogger().handlers:  # whatever logger a token or key reaches it by
        if not any(isinstance(f, RedactSecrets) for f in handler.filters):  # main() run again
            handler.addFilter(RedactSecrets())
