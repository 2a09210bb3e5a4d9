"""``skelfuse`` command line. Imports stay inside the subcommands so that an agent-only install
(numpy, pyzmq, msgpack) never touches the server's dependencies."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.agent.sources.registry import SOURCE_KINDS
from skelfuse.protocol.constants import DEFAULT_HTTP_PORT, DEFAULT_ZMQ_PORT

if TYPE_CHECKING:
    from skelfuse.fusion.settings import FusionSettings


class UsageError(Exception):
    """A command-line value that cannot be used; the message says what to type instead."""


def parse_pose(text: str) -> tuple[tuple[float, float, float], float, float]:
    """``X,Y,Z,YAW_DEG[,PITCH_DEG]`` -> position, yaw, pitch."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise UsageError(f"--pose {text!r}: expected numbers X,Y,Z,YAW_DEG[,PITCH_DEG]") from exc
    if len(values) not in (4, 5) or not all(map(_finite, values)):
        raise UsageError(
            f"--pose {text!r}: expected 4 or 5 finite numbers X,Y,Z,YAW_DEG[,PITCH_DEG]"
        )
    pitch = values[4] if len(values) == 5 else 0.0
    if not -90.0 <= pitch <= 90.0:
        raise UsageError(f"--pose pitch {pitch} must be within -90..90 degrees")
    return (values[0], values[1], values[2]), values[3], pitch


def _finite(x: float) -> bool:
    return x == x and abs(x) != float("inf")


def parse_host_port(text: str, default_port: int) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep:
        return text, default_port
    try:
        number = int(port)
    except ValueError as exc:
        raise UsageError(f"{text!r}: the port must be a number") from exc
    if not 0 < number < 65536:
        raise UsageError(f"{text!r}: port out of range")
    return host.strip("[]") or "127.0.0.1", number


def _configure_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )


def _stop_on_signals() -> threading.Event:
    stop = threading.Event()

    def handler(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


# --- subcommands ----------------------------------------------------------------------------


def fusion_settings(path: str | None) -> FusionSettings:
    """Defaults, or the deployment's file; a bad file stops the command with its problems."""
    from skelfuse.fusion.config import FusionConfigError, load_fusion_settings
    from skelfuse.fusion.settings import FusionSettings

    if path is None:
        return FusionSettings()
    try:
        return load_fusion_settings(path)
    except FusionConfigError as exc:
        raise UsageError(str(exc)) from exc


def cmd_server(args: argparse.Namespace) -> int:
    try:
        import uvicorn

        from skelfuse.server.app import create_app
        from skelfuse.server.settings import Settings
    except ImportError as exc:
        raise UsageError(
            f"the server needs its extra dependencies ({exc.name} is missing): "
            "pip install 'skelfuse[server]'"
        ) from exc
    host, port = parse_host_port(args.http, DEFAULT_HTTP_PORT)
    token = args.token or os.environ.get("SKELFUSE_TOKEN") or None
    if args.curve:
        from skelfuse.server.auth import KeysMissing, server_keys

        try:
            server_keys(Path(args.data))  # fail closed, and say how to fix it
        except KeysMissing as exc:
            raise UsageError(str(exc)) from exc
    fusion = fusion_settings(args.fusion_config)
    settings = Settings(
        fusion=fusion,
        http_host=host,
        http_port=port,
        zmq_endpoint=args.zmq,
        data_dir=Path(args.data),
        api_token=token,
        allowed_origins=tuple(args.allow_origin or ()),
        curve=args.curve,
    )
    if token is None and host not in ("127.0.0.1", "localhost", "::1"):
        logging.getLogger("skelfuse").warning(
            "serving %s without --token: anyone on the network can change calibration", host
        )
    config = uvicorn.Config(
        create_app(settings),
        host=host,
        port=port,
        log_level=args.log_level.lower(),
        ws_max_size=64 * 1024,
        # A client that stops reading stops answering pings long before the kernel's socket
        # buffers (megabytes) fill: this is what disconnects it within about 10 s.
        ws_ping_interval=5.0,
        ws_ping_timeout=5.0,
        lifespan="on",
    )
    server = uvicorn.Server(config)
    server.run()
    return 0 if server.started else 1


def cmd_agent(args: argparse.Namespace) -> int:
    import time

    from skelfuse.agent.runner import run_agent
    from skelfuse.cli_ext import source_from_args

    args.pose_given = args.pose is not None
    source = source_from_args(args)
    curve = None
    if args.key or args.server_key:
        if not (args.key and args.server_key):
            raise UsageError(
                "CurveZMQ needs both --key (this agent's .key_secret) and --server-key"
            )
        from skelfuse.agent.link import CurveKeys

        curve = CurveKeys(Path(args.key), Path(args.server_key))
    stop = _stop_on_signals()
    started = time.monotonic()
    link = run_agent(args.id, source, args.server, stop=stop, duration_s=args.duration, curve=curve)
    logging.getLogger("skelfuse.agent").info(
        "%s stopped after %.0f s: %d frames sent, %d dropped",
        args.id,
        time.monotonic() - started,
        link.stats.frames_sent,
        link.stats.frames_dropped,
    )
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
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


def cmd_demo(args: argparse.Namespace) -> int:
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
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="skelfuse",
        description="Markerless multi-sensor motion capture: agents, fusion server, live demo.",
    )
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING (default INFO)")
    sub = parser.add_subparsers(dest="command", required=True)

    server = sub.add_parser("server", help="run the fusion server")
    server.add_argument(
        "--http",
        default=f"127.0.0.1:{DEFAULT_HTTP_PORT}",
        help="HOST:PORT for REST, WebSocket and the viewer (default %(default)s)",
    )
    server.add_argument(
        "--zmq",
        default=f"tcp://*:{DEFAULT_ZMQ_PORT}",
        help="ZeroMQ endpoint agents connect to (default %(default)s)",
    )
    server.add_argument(
        "--data",
        default="skelfuse-data",
        help="folder for calibration and recordings (default %(default)s)",
    )
    server.add_argument(
        "--token",
        default=None,
        help="require this token for REST changes and the WebSocket (or set SKELFUSE_TOKEN)",
    )
    server.add_argument(
        "--allow-origin",
        action="append",
        default=None,
        metavar="ORIGIN",
        help="another browser origin allowed on the WebSocket (repeatable)",
    )
    server.add_argument(
        "--fusion-config",
        default=os.environ.get("SKELFUSE_FUSION_CONFIG") or None,
        metavar="FILE",
        help="TOML file with a [fusion] table overriding fusion settings (docs/fusion.md §9; "
        "or set SKELFUSE_FUSION_CONFIG)",
    )
    server.add_argument(
        "--curve",
        action="store_true",
        help="authenticate agents with CurveZMQ keys from <data>/keys ('skelfuse keys create')",
    )
    server.set_defaults(func=cmd_server)

    agent = sub.add_parser("agent", help="run a capture agent for one sensor")
    agent.add_argument(
        "--source",
        default="sim",
        choices=list(SOURCE_KINDS),
        help="sensor source; 'skelfuse doctor' says which can run on this PC",
    )
    agent.add_argument(
        "--server",
        default=f"tcp://127.0.0.1:{DEFAULT_ZMQ_PORT}",
        help="the server's ZeroMQ endpoint, tcp://HOST:PORT (default %(default)s)",
    )
    agent.add_argument("--id", required=True, help="this sensor's unique id, e.g. kinect-front")
    agent.add_argument(
        "--pose",
        default=None,
        help="X,Y,Z,YAW_DEG[,PITCH_DEG]: sim: where the simulated sensor stands (default "
        "0,1.0,3.0,180); real sensors: a hand-measured pose sent as a hint until calibrated "
        "(metres, Y up; yaw 0 looks along +Z, 90 along +X; +pitch looks down); "
        "write --pose=-2,1,3,90 when X is negative",
    )
    agent.add_argument("--persons", type=int, default=2, help="sim: people in the room (1-6)")
    agent.add_argument("--seed", type=int, default=None, help="sim: noise seed (default: from id)")
    agent.add_argument(
        "--clock-offset-ms",
        type=float,
        default=0.0,
        help="sim: pretend this PC's clock is off by this much",
    )
    agent.add_argument(
        "--clock-drift-ppm",
        type=float,
        default=0.0,
        help="sim: pretend this PC's clock runs fast (or slow, if negative) by this much",
    )
    agent.add_argument(
        "--no-pose-hint",
        dest="pose_hint",
        action="store_false",
        help="sim: do not tell the server the true pose (calibrate instead)",
    )
    agent.add_argument("--key", default=None, help="CurveZMQ: this agent's <id>.key_secret file")
    agent.add_argument(
        "--server-key", default=None, help="CurveZMQ: the server's public key file (server.key)"
    )
    agent.add_argument("--duration", type=float, default=None, help="stop after N seconds")
    agent.set_defaults(func=cmd_agent)

    from skelfuse import cli_ext

    cli_ext.add_source_arguments(agent)

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
    keys.set_defaults(func=cmd_keys)

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
    demo.set_defaults(func=cmd_demo)
    cli_ext.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    _configure_logging(args.log_level)
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
