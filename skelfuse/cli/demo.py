"""``skelfuse demo``: server, simulated sensors and viewer on this machine (skelfuse.demo)."""

from __future__ import annotations

import argparse
from pathlib import Path

from skelfuse.cli.values import parse_host_port
from skelfuse.protocol.constants import DEFAULT_HTTP_PORT, DEFAULT_ZMQ_PORT


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``demo`` and its options to the command line."""
    demo = sub.add_parser("demo", help="server + simulated sensors + viewer on this machine")
    demo.add_argument("--sensors", type=int, default=3, help="simulated sensors (1-8)")
    demo.add_argument("--persons", type=int, default=2, help="simulated people (1-6)")
    demo.add_argument("--http", default=f"127.0.0.1:{DEFAULT_HTTP_PORT}", help="HOST:PORT")
    demo.add_argument("--zmq-port", type=int, default=DEFAULT_ZMQ_PORT, help="agent port")
    demo.add_argument("--data", default=None, help="data folder (default: a temporary one)")
    demo.add_argument(
        "--calibration",
        choices=["auto", "truth"],
        default="auto",
        help="auto: calibrate through the REST API as a user would (default); truth: use the "
        "simulator's true sensor poses",
    )
    demo.add_argument(
        "--token", default=None, help="API token for REST changes and the feed (default: random)"
    )
    demo.add_argument("--duration", type=float, default=None, help="stop after N seconds")
    demo.add_argument(
        "--recalibrate",
        action="store_true",
        help="with --data: calibrate again even when the folder holds a calibration of every "
        "sensor (by default the demo restarts with it)",
    )
    demo.add_argument(
        "--access-log",
        action="store_true",
        help="the server logs every HTTP request (off by default: the viewer polls)",
    )
    demo.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demo until Ctrl-C or ``--duration``; its exit status.

    Raises:
        UsageError: a bad ``--http``.
    """
    from skelfuse.demo import run_demo

    return run_demo(
        sensors=args.sensors,
        persons=args.persons,
        http=parse_host_port(args.http, DEFAULT_HTTP_PORT),
        zmq_port=args.zmq_port,
        data_dir=Path(args.data) if args.data else None,
        duration_s=args.duration,
        log_level=args.log_level,
        calibration=args.calibration,
        token=args.token,
        recalibrate=args.recalibrate,
        access_log=args.access_log,
    )
