"""The FastAPI application: REST, the WebSocket feed, the viewer, and the background tasks."""

from __future__ import annotations

import asyncio
import gc
import logging
import time
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import zmq
import zmq.asyncio
from fastapi import FastAPI, Query, WebSocket
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles
from prometheus_client import CollectorRegistry, make_asgi_app

from skelfuse import __version__
from skelfuse.calibration.store import Calibration, CalibrationStore
from skelfuse.fusion.engine import warm_up
from skelfuse.protocol.feed import persons_json
from skelfuse.protocol.skeleton import skeleton_definition
from skelfuse.server import (
    openapi,
    routes_calibration,
    routes_fusion,
    routes_recordings,
    routes_sensors,
)
from skelfuse.server.agent_requests import AgentRequests
from skelfuse.server.auth import SensorAuthenticator
from skelfuse.server.body_limit import BodyLimit
from skelfuse.server.broadcast import (
    PREFRAMED,
    Broadcaster,
    Outgoing,
    PersonsQuery,
    Variant,
    encode_message,
    persons_orientations,
)
from skelfuse.server.calibration_runs import CalibrationService
from skelfuse.server.clock import SystemClock
from skelfuse.server.depth_clouds import LatestClouds
from skelfuse.server.errors import (
    HANDLED_ERRORS,
    error_response,
    invalid_body_response,
    method_not_allowed_response,
)
from skelfuse.server.hub import FusionHub
from skelfuse.server.ingest import fusion_loop, ingest_loop, liveness_loop, open_router, send_to
from skelfuse.server.log_redaction import redact_uvicorn_logs
from skelfuse.server.loop_lag import LoopLagCollector, LoopLagMonitor
from skelfuse.server.metrics import SkelfuseCollector
from skelfuse.server.outputs import Fanout, OutputsCollector, QueuedOutput, build_output
from skelfuse.server.security import HttpGuard, origin_ok, token_ok
from skelfuse.server.sensors_answer import SensorsAnswer, sensors_answer
from skelfuse.server.settings import Settings
from skelfuse.server.stage_timing import StageTimes, StageTimesCollector

logger = logging.getLogger(__name__)
STATIC_DIR = Path(__file__).parent / "static"


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the server. Sockets open and tasks start in the lifespan (on server start-up)."""
    settings = settings or Settings()
    redact_uvicorn_logs()  # the feed's ?token= must not reach the access log (issue 12)
    registry = CollectorRegistry()  # per app, so tests can run several servers in one process
    app = FastAPI(
        title="skelfuse fusion server",
        version=__version__,
        description="Fused multi-sensor skeletons: REST for state and control; the live feed "
        "is the WebSocket `/ws/skeletons` (see docs/api.md).",
        lifespan=_lifespan(settings, registry),
    )
    app.state.settings = settings
    app.state.recording = None
    _add_error_handlers(app)
    _add_status_routes(app)
    _add_feed_route(app, settings)
    app.include_router(routes_calibration.router)
    app.include_router(routes_recordings.router)
    app.include_router(routes_fusion.router)
    app.include_router(routes_sensors.router)
    app.add_middleware(HttpGuard, settings=settings)
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)  # outermost: before the token
    app.mount("/metrics", make_asgi_app(registry))
    openapi.install(app, settings.api_token is not None, settings.max_body_bytes)
    _add_viewer(app)
    return app


def _lifespan(
    settings: Settings, registry: CollectorRegistry
) -> Callable[[FastAPI], AbstractAsyncContextManager[None]]:
    """The server's run: start-up before the ``yield``, shut-down after it, in reverse."""

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = CalibrationStore(settings.data_dir)
        hub = FusionHub(settings, _load_calibration(store))
        await _warm_up_fusion_kernels()
        _freeze_start_up_objects()
        broadcaster = Broadcaster(settings.ws_send_timeout_s)
        link = _AgentLink.open(settings)
        agents = AgentRequests(
            hub, lambda routing_id, message: send_to(link.socket, routing_id, message)
        )
        hub.attach_requests(agents)
        _attach_services(app, hub, store, agents)
        loop_lag, stages = _attach_monitors(app, registry, hub, broadcaster)
        outputs = _start_outputs(settings, registry)
        app.state.outputs = outputs
        app.state.zmq_endpoint = link.socket.getsockopt_string(zmq.LAST_ENDPOINT)
        logger.info("agents connect to %s", app.state.zmq_endpoint)
        tasks = [
            asyncio.create_task(
                ingest_loop(link.socket, hub, settings.curve, stages), name="ingest"
            ),
            asyncio.create_task(
                liveness_loop(link.socket, hub, settings.heartbeat_interval_s), name="liveness"
            ),
            asyncio.create_task(
                fusion_loop(hub, Fanout([broadcaster, *outputs]), stages), name="fusion"
            ),
            asyncio.create_task(loop_lag.run(), name="loop-lag"),
        ]
        try:
            yield
        finally:
            _close_recording(app, hub)
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for output in outputs:  # joins its thread: off the event loop
                await asyncio.to_thread(output.close)
            await app.state.calibration.close()  # and its solver worker process
            link.close()
            gc.unfreeze()  # a process that starts another server (tests) collects it again

    return lifespan


def _load_calibration(store: CalibrationStore) -> Calibration | None:
    """The stored calibration, if any, said in the log."""
    calibration = store.load()
    if calibration is not None:
        logger.info(
            "loaded calibration v%d for %s",
            calibration.version,
            ", ".join(sorted(calibration.sensors)) or "no sensors",
        )
    return calibration


async def _warm_up_fusion_kernels() -> None:
    """Compile the fusion stages' loops (or load numba's cache) off the event loop, now rather
    than in the first fusion step; the first start on a machine compiles, so say why nothing
    answers yet."""
    logger.info("fusion kernels: loading numba's cache (a first start compiles, ~25 s)")
    started = time.perf_counter()
    await asyncio.to_thread(warm_up)
    logger.info("fusion kernels ready in %.2f s", time.perf_counter() - started)


def _freeze_start_up_objects() -> None:
    """Move what start-up made out of the cycle collector's reach (``gc.unfreeze`` undoes it)."""
    # What start-up made (modules, classes, caches) lives as long as the process: out of the
    # cycle collector's reach, a full collection no longer walks it on the event loop (one
    # took 154 ms during a calibration, bench/live/calibration_stall.py; issue 11 item 5).
    gc.collect()
    gc.freeze()


@dataclass(frozen=True)
class _AgentLink:
    """The agents' side of ZeroMQ: the context, the CurveZMQ authenticator (if on), the ROUTER."""

    context: zmq.asyncio.Context
    authenticator: SensorAuthenticator | None
    socket: zmq.asyncio.Socket

    @classmethod
    def open(cls, settings: Settings) -> _AgentLink:
        """Start the authenticator (with ``settings.curve``) and bind the ROUTER socket."""
        context = zmq.asyncio.Context()
        authenticator = None
        if settings.curve:
            authenticator = SensorAuthenticator(context, settings.data_dir)
            authenticator.start()
        socket = open_router(
            context, settings.zmq_endpoint, settings.data_dir if settings.curve else None
        )
        return cls(context, authenticator, socket)

    def close(self) -> None:
        """Close the socket at once (nothing queued is sent), stop the authenticator, end ZeroMQ."""
        self.socket.close(linger=0)
        if self.authenticator is not None:
            self.authenticator.stop()
        self.context.term()


def _attach_services(
    app: FastAPI, hub: FusionHub, store: CalibrationStore, agents: AgentRequests
) -> None:
    """The hub and the services the routes reach through ``app.state``."""
    app.state.hub = hub
    app.state.calibration = CalibrationService(hub, store, agents)
    app.state.clouds = LatestClouds(  # viewers' depth clouds (routes_sensors)
        agents, lambda s: hub.sensors[s].clock_offset_s if s in hub.sensors else None,
        SystemClock(),
    )  # fmt: skip


def _attach_monitors(
    app: FastAPI, registry: CollectorRegistry, hub: FusionHub, broadcaster: Broadcaster
) -> tuple[LoopLagMonitor, StageTimes]:
    """Register the hub's, the event loop's and the live path's metrics; the broadcaster in
    ``app.state``. Returns the loop-lag monitor (its task to start) and the stage timer."""
    registry.register(SkelfuseCollector(hub, broadcaster))
    loop_lag = LoopLagMonitor(SystemClock())
    registry.register(LoopLagCollector(loop_lag))
    app.state.loop_lag = loop_lag
    stages = StageTimes()  # where the live path's time goes (bench/live/load.py reads it)
    broadcaster.send_times = stages.send
    registry.register(StageTimesCollector(stages))
    app.state.broadcaster = broadcaster
    return loop_lag, stages


def _start_outputs(settings: Settings, registry: CollectorRegistry) -> list[QueuedOutput]:
    """Start the configured outputs and register their metrics."""
    # OSC, VMC, LSL: each its own queue and thread; the feed stays first (docs/outputs.md)
    outputs = [build_output(spec, settings.output_hz) for spec in settings.outputs]
    for output in outputs:
        output.start()
        logger.info("output %s started", output.name)
    registry.register(OutputsCollector(outputs))
    return outputs


def _close_recording(app: FastAPI, hub: FusionHub) -> None:
    """Close a recording still running properly, with its end record."""
    active = app.state.recording
    if active is not None:
        hub.stop_tap()
        active[1].close()


def _add_error_handlers(app: FastAPI) -> None:
    """Routes raise; these turn errors into responses (server/errors.py)."""
    for error in HANDLED_ERRORS:
        app.exception_handler(error)(error_response)
    app.exception_handler(RequestValidationError)(invalid_body_response)
    app.exception_handler(405)(method_not_allowed_response)


def _hub_of(app: FastAPI) -> FusionHub:
    hub: FusionHub = app.state.hub
    return hub


def _add_status_routes(app: FastAPI) -> None:
    """The read-only status routes: health, sensors, persons, skeleton, feed clients."""

    @app.get("/api/health", tags=["status"])
    async def health() -> dict[str, object]:
        hub = _hub_of(app)
        latest = hub.latest
        return {
            "status": "ok",
            "version": __version__,
            "uptime_s": round(time.time() - hub.started_s, 3),
            "sensors_online": sum(s.connected for s in hub.sensors.values()),
            "sensors_known": len(hub.sensors),
            "persons": 0 if latest is None else len(latest.persons),
            "fused_frames": 0 if latest is None else latest.seq,
            "ws_clients": len(app.state.broadcaster.clients),
            "zmq_endpoint": app.state.zmq_endpoint,
        }

    @app.get("/api/sensors", tags=["status"])
    async def sensors() -> SensorsAnswer:
        hub = _hub_of(app)
        return sensors_answer(
            hub.sensor_summary(time.monotonic()),
            hub.pipeline.errors.summary(),
            hub.rejected_unregistered,
        )

    @app.get("/api/persons", tags=["status"])
    async def persons(query: Annotated[PersonsQuery, Query()]) -> dict[str, object]:
        latest = _hub_of(app).latest
        if latest is None:
            return {"seq": 0, "t": None, "persons": []}
        joint_rotations = persons_orientations(latest.persons) if query.rotations else None
        return {
            "seq": latest.seq,
            "t": round(latest.t_s, 6),
            "persons": persons_json(latest.persons, orientations=joint_rotations),
        }

    @app.get("/api/skeleton", tags=["status"])
    async def skeleton() -> dict[str, object]:
        return skeleton_definition()

    @app.get("/api/clients", tags=["status"])
    async def clients() -> dict[str, object]:
        broadcaster: Broadcaster = app.state.broadcaster
        return {"clients": broadcaster.stats(), "evicted": broadcaster.evicted}


def _add_feed_route(app: FastAPI, settings: Settings) -> None:
    """The live feed, ``/ws/skeletons``: token and origin checked before the handshake."""

    @app.websocket("/ws/skeletons")
    async def skeletons(
        websocket: WebSocket,
        format: Literal["json", "msgpack"] = Query("json"),
        raw: bool = Query(False),
        rotations: bool = Query(False),
        token: str | None = Query(None),
    ) -> None:
        if not token_ok(settings.api_token, token):
            await websocket.close(code=1008, reason="missing or wrong token")
            return
        origin = websocket.headers.get("origin")
        if not origin_ok(origin, websocket.headers.get("host"), settings.allowed_origins):
            await websocket.close(code=1008, reason="origin not allowed")
            return
        await websocket.accept()
        broadcaster: Broadcaster = app.state.broadcaster
        binary = format == "msgpack"
        variant = Variant(binary, raw, rotations)
        client = broadcaster.add(variant, str(websocket.client), time.time())
        greeting = encode_message(skeleton_definition(), binary)
        await broadcaster.serve(client, _WebSocketFeed(websocket), greeting)


def _add_viewer(app: FastAPI) -> None:
    """The browser viewer: its page at ``/`` and its files under ``/static``."""

    @app.get("/", include_in_schema=False)
    async def index() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html")

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")


class _WebSocketFeed:
    """Starlette's WebSocket as the broadcaster's :class:`FeedSocket`."""

    def __init__(self, websocket: WebSocket) -> None:
        self._websocket = websocket
        # skelfuse server's uvicorn protocol writes the broadcaster's shared framing as is, and
        # offers the broadcaster's cheap path (server/feed_protocol.py)
        extension = (websocket.scope.get("extensions") or {}).get(PREFRAMED)
        self._preframed = extension is not None
        if isinstance(extension, dict) and "write_now" in extension:
            write_now = extension["write_now"]
            self.write_now = lambda message: bool(write_now(message.framed))
            self.ready = extension["ready"]

    async def send(self, message: Outgoing) -> None:
        if self._preframed:
            await self._websocket.send({"type": "websocket.send", PREFRAMED: message.framed})
        elif isinstance(message.payload, bytes):
            await self._websocket.send_bytes(message.payload)
        else:
            await self._websocket.send_text(message.payload)

    async def closed(self) -> None:
        while True:  # what the client sends is ignored; reading it notices the disconnect
            message = await self._websocket.receive()
            if message["type"] == "websocket.disconnect":
                return

    async def close(self, code: int, reason: str) -> None:
        await self._websocket.close(code=code, reason=reason)
