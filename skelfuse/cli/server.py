"""``skelfuse server``: the fusion server (REST, WebSocket feed, viewer, agents over ZeroMQ)."""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skelfuse.cli.values import UsageError, fusion_settings, parse_host_port
from skelfuse.protocol.constants import DEFAULT_HTTP_PORT, DEFAULT_ZMQ_PORT

if TYPE_CHECKING:
    import uvicorn


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``server`` and its options to the command line."""
    server = sub.add_parser("server", help="run the fusion server")
    _add_server_options(server)
    _add_output_options(server.add_argument_group("outputs (docs/outputs.md)"))
    server.set_defaults(func=run)


def _add_server_options(server: argparse.ArgumentParser) -> None:
    """The server's own options: where it listens, its data, its security, its logging."""
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
        "--ws-compression",
        action="store_true",
        help="offer permessage-deflate on the WebSocket feed (off by default: it compresses "
        "each frame once per client; worth it only for clients on slow links)",
    )
    server.add_argument(
        "--curve",
        action="store_true",
        help="authenticate agents with CurveZMQ keys from <data>/keys ('skelfuse keys create')",
    )
    server.add_argument(
        "--access-log",
        action="store_true",
        help="log every HTTP request (off by default: the viewer polls, one line each)",
    )


def _add_output_options(outputs: argparse._ArgumentGroup) -> None:
    """Where fused frames go besides the WebSocket feed: OSC, VMC, LSL, NATS, a TOML file."""
    outputs.add_argument(
        "--osc", action="append", default=None, metavar="HOST:PORT",
        help="send fused frames as OSC bundles over UDP to HOST:PORT (repeatable)",
    )  # fmt: skip
    outputs.add_argument(
        "--osc-rotations", action="store_true", help="OSC: add each joint's rotation (/rot)"
    )
    outputs.add_argument(
        "--vmc", action="append", default=None, metavar="HOST[:PORT]",
        help="send the fused skeleton as a VMC protocol avatar (port 39539 if not given)",
    )  # fmt: skip
    outputs.add_argument(
        "--lsl", action="store_true", help="publish fused skeletons as Lab Streaming Layer streams"
    )
    outputs.add_argument(
        "--nats", default=None, metavar="HOST[:PORT]",
        help="publish fused frames (msgpack) to NATS at HOST (port 4222 if not given)",
    )  # fmt: skip
    outputs.add_argument(
        "--nats-room", default="default", metavar="NAME",
        help="NATS: this server's room; frames go to skelfuse.NAME.frames (default: default)",
    )  # fmt: skip
    outputs.add_argument(
        "--nats-history", type=int, default=None, metavar="SECONDS",
        help="NATS: keep the last SECONDS of frames in a JetStream stream for late subscribers",
    )  # fmt: skip
    outputs.add_argument(
        "--outputs-config", default=None, metavar="FILE",
        help="TOML file with [[outputs]] tables (kind = osc|vmc|lsl|nats, host, port, ...)",
    )  # fmt: skip


def output_specs(args: argparse.Namespace) -> tuple[Any, ...]:
    """The ``OutputSpec`` of ``--outputs-config``'s tables, then of ``--osc``, ``--vmc``,
    ``--lsl``, ``--nats``.

    Raises:
        UsageError: a bad HOST:PORT, file or NATS room; ``--osc`` without a port; ``--lsl``
            without pylsl; ``--nats`` without nats-py.
    """
    from skelfuse.server.output_config import (
        VMC_PORT,
        OutputConfigError,
        load_outputs,
        output_from_mapping,
    )
    from skelfuse.server.output_nats import NATS_PORT
    from skelfuse.server.settings import OutputSpec

    specs: list[OutputSpec] = []
    if args.outputs_config is not None:
        try:
            specs.extend(load_outputs(args.outputs_config))
        except OutputConfigError as exc:
            raise UsageError(str(exc)) from exc
    for text in args.osc or ():
        host, port = parse_host_port(text, 0)
        if port == 0:
            raise UsageError(f"--osc {text!r}: give the receiver's port, HOST:PORT")
        specs.append(OutputSpec("osc", host, port, rotations=args.osc_rotations))
    for text in args.vmc or ():
        host, port = parse_host_port(text, VMC_PORT)
        specs.append(OutputSpec("vmc", host, port))
    if args.lsl:
        specs.append(OutputSpec("lsl"))
    if args.nats is not None:
        host, port = parse_host_port(args.nats, NATS_PORT)
        table: dict[str, object] = {"kind": "nats", "host": host, "port": port}
        table["room"] = args.nats_room
        if args.nats_history is not None:
            table |= {"jetstream": True, "history_s": args.nats_history}
        try:
            specs.append(output_from_mapping(table, "--nats"))
        except OutputConfigError as exc:
            raise UsageError(str(exc)) from exc
    if any(spec.kind == "nats" for spec in specs):
        try:
            import nats  # noqa: F401
        except ImportError as exc:
            raise UsageError("--nats needs nats-py: pip install 'skelfuse[nats]'") from exc
    if any(spec.kind == "lsl" for spec in specs):
        try:
            import pylsl  # noqa: F401
        except ImportError as exc:
            raise UsageError("--lsl needs pylsl: pip install 'skelfuse[lsl]'") from exc
    return tuple(specs)


def run(args: argparse.Namespace) -> int:
    """Serve until stopped (SIGINT/SIGTERM); 0 after a clean stop, 1 if it never started.

    Raises:
        UsageError: the server extras are not installed, ``--curve`` without keys, a bad
            ``--http`` or ``--fusion-config``.
    """
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
    check_agent_endpoint(args.zmq)
    settings = Settings(
        fusion=fusion,
        http_host=host,
        http_port=port,
        zmq_endpoint=args.zmq,
        data_dir=Path(args.data),
        api_token=token,
        allowed_origins=tuple(args.allow_origin or ()),
        curve=args.curve,
        outputs=output_specs(args),
    )
    if token is None and host not in ("127.0.0.1", "localhost", "::1"):
        logging.getLogger("skelfuse").warning(
            "serving %s without --token: anyone on the network can change calibration", host
        )
    config = uvicorn_config(
        create_app(settings),
        host,
        port,
        args.log_level.lower(),
        args.ws_compression,
        access_log=args.access_log,
    )
    server = uvicorn.Server(config)
    server.run()
    return 0 if server.started else 1


def check_agent_endpoint(endpoint: str) -> None:
    """Fail before anything starts when the agent endpoint cannot be bound.

    The server binds it while starting up, where a failure reaches the user as uvicorn's
    startup traceback; most often another skelfuse server holds the port, which one line says.

    Raises:
        OSError: the endpoint cannot be bound (in use, no such address, bad syntax).
    """
    import zmq

    context = zmq.Context()
    socket = context.socket(zmq.ROUTER)
    try:
        socket.bind(endpoint)
    except zmq.ZMQError as exc:
        raise OSError(
            f"cannot bind the agent endpoint {endpoint}: {exc.strerror} "
            "(is another skelfuse server running? choose another with --zmq)"
        ) from exc
    finally:
        socket.close(linger=0)
        context.term()


def uvicorn_config(
    app: Any,
    host: str,
    port: int,
    log_level: str,
    ws_compression: bool,
    *,
    access_log: bool = False,
) -> uvicorn.Config:
    """How ``skelfuse server`` runs uvicorn: the WebSocket limits, pings and compression.

    ``access_log``: a line per HTTP request, and uvicorn's lines per WebSocket connection (its
    error log's "WebSocket /path" [accepted], "connection open", "connection closed"). Off by
    default (issue 13): the viewer polls the REST API every second or so, and those lines
    scroll away what the terminal says once.

    ``ws_compression``: negotiate permessage-deflate with clients that offer it. Off by default
    because the deflate stream is per connection: every frame is compressed again for every
    client (issue 11: 200 clients fell to 13.9 frames/s with it, 29.7 without).
    """
    import uvicorn

    from skelfuse.server.feed_protocol import FeedWebSocketProtocol

    config = uvicorn.Config(
        app,
        host=host,
        port=port,
        log_level=log_level,
        access_log=access_log,
        # Send buffers of about one frame, so the feed conflates instead of queueing in the
        # kernel (issue 12, defect 2); a client that stops reading is then evicted by the
        # broadcaster (1008, 5 s) before the keepalive below would cut it (1011, about 10 s).
        ws=FeedWebSocketProtocol,
        ws_max_size=64 * 1024,
        # The keepalive is for peers that vanished without closing.
        ws_ping_interval=5.0,
        ws_ping_timeout=5.0,
        ws_per_message_deflate=ws_compression,
        lifespan="on",
    )
    # After Config, which configures uvicorn's loggers; addFilter is idempotent.
    error_log = logging.getLogger("uvicorn.error")
    if access_log:
        error_log.removeFilter(QUIET_WEBSOCKETS)
    else:
        error_log.addFilter(QUIET_WEBSOCKETS)
    return config


class _QuietWebSockets(logging.Filter):
    """Drops uvicorn's lines per WebSocket connection: the feed's counterpart of the access log."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = str(record.msg)
        return not (
            message.startswith('%s - "WebSocket %s"')
            or message in ("connection open", "connection closed")
        )


QUIET_WEBSOCKETS = _QuietWebSockets()
