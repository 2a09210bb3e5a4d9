"""HTTP-side protection on a real server: token, browser origins, body size."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from fastapi.routing import APIRoute
from starlette.routing import Route
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from skelfuse.server.app import create_app
from skelfuse.server.settings import Settings
from tests.integration.conftest import LiveServer

pytestmark = pytest.mark.timeout(60)
TOKEN = "s3cret-token"


@pytest.fixture
def guarded(server_factory: Callable[..., LiveServer]) -> LiveServer:
    return server_factory(api_token=TOKEN, allowed_origins=("http://dashboard.lan:3000",))


def test_mutations_need_the_token_reads_do_not(guarded: LiveServer) -> None:
    url = guarded.http_url + "/api/calibration/runs"
    refused = httpx.post(url, json={"method": "auto"})
    assert refused.status_code == 401
    assert "Bearer" in refused.json()["detail"]
    wrong = httpx.post(url, json={"method": "auto"}, headers={"Authorization": "Bearer nope"})
    assert wrong.status_code == 401
    right = httpx.post(url, json={"method": "auto"}, headers={"Authorization": f"Bearer {TOKEN}"})
    assert right.status_code == 409  # authorised; refused only because no sensor is connected
    assert httpx.get(guarded.http_url + "/api/health").status_code == 200


# Reads that return people's motion or body measurements (docs/security.md); every other read
# here is status a dashboard may show without the token. A new GET route must be added to one of
# the two lists: the test below fails on a route in neither.
PERSONAL_READS = {
    "/api/persons",
    "/api/persons/{person_id}/bones",
    "/api/recordings",
    "/api/recordings/{recording_id}/download",
    "/api/sensors/{sensor_id}/cloud",
    "/api/sensors/{sensor_id}/bodies",
}
OPEN_READS = {
    "/api/health", "/api/sensors", "/api/skeleton", "/api/clients", "/api/calibration",
    "/api/calibration/runs", "/api/calibration/runs/{run_id}", "/api/calibration/history",
    "/api/calibration/export", "/api/fusion/settings", "/", "/openapi.json", "/docs",
    "/docs/oauth2-redirect", "/redoc",
}  # fmt: skip


def test_every_read_of_people_needs_the_token_status_reads_do_not(guarded: LiveServer) -> None:
    app = guarded.server.config.app
    gets = {r.path for r in app.routes if isinstance(r, APIRoute | Route) and "GET" in r.methods}
    assert gets - PERSONAL_READS - OPEN_READS == set(), "classify the new route(s) above"
    for template in sorted(gets):
        url = guarded.http_url + template.format(
            person_id=1, recording_id="x", run_id="x", sensor_id="x"
        )
        anonymous = httpx.get(url)
        if template in PERSONAL_READS:
            assert anonymous.status_code == 401, template
            assert "Bearer" in anonymous.json()["detail"]
            assert httpx.get(url, headers={"Authorization": "Bearer nope"}).status_code == 401
        else:
            assert anonymous.status_code in (200, 404), (template, anonymous.status_code)
        authorised = httpx.get(url, headers={"Authorization": f"Bearer {TOKEN}"})
        assert authorised.status_code in (200, 404), (template, authorised.status_code)
    for path in ("/metrics", "/metrics/"):  # Prometheus scrapers carry no token
        assert httpx.get(guarded.http_url + path, follow_redirects=True).status_code == 200


async def test_the_rule_holds_under_a_path_prefix(tmp_path: Path) -> None:
    """Behind a proxy that mounts the server under a prefix (ASGI ``root_path``), the paths the
    rule names are still the app's own."""
    app = create_app(Settings(api_token=TOKEN, data_dir=tmp_path))
    transport = httpx.ASGITransport(app=app, root_path="/skelfuse")
    async with httpx.AsyncClient(transport=transport, base_url="http://lab") as client:
        assert (await client.get("/skelfuse/api/persons")).status_code == 401
        assert (await client.get("/skelfuse/api/recordings/x/download")).status_code == 401


def test_persons_is_open_without_a_token(live_server: LiveServer) -> None:
    assert httpx.get(live_server.http_url + "/api/persons").status_code == 200


def test_oversized_bodies_are_refused_before_reading(guarded: LiveServer) -> None:
    response = httpx.post(
        guarded.http_url + "/api/calibration/import",
        content=b"{" + b" " * (2 * 1024 * 1024) + b"}",
        headers={"Authorization": f"Bearer {TOKEN}", "content-type": "application/json"},
    )
    assert response.status_code == 413


async def test_websocket_needs_token_and_a_trusted_origin(guarded: LiveServer) -> None:
    feed = guarded.ws_url + "/ws/skeletons"
    with pytest.raises(InvalidStatus):
        async with connect(feed):
            pass
    with pytest.raises(InvalidStatus):
        async with connect(feed + f"?token={TOKEN}", origin="http://evil.example"):  # type: ignore[arg-type]
            pass
    for origin in (None, f"http://127.0.0.1:{guarded.settings.http_port}",
                   "http://dashboard.lan:3000"):  # fmt: skip
        async with connect(feed + f"?token={TOKEN}", origin=origin) as ws:  # type: ignore[arg-type]
            assert '"skeleton"' in str(await ws.recv())


async def test_the_token_is_not_in_the_server_logs(
    guarded: LiveServer, caplog: pytest.LogCaptureFixture
) -> None:
    """uvicorn logs every request's path with its query string (access log) and every WebSocket
    handshake (``uvicorn.error``): the feed's ``?token=`` must be masked in both."""
    loggers = [logging.getLogger(name) for name in ("uvicorn.access", "uvicorn.error")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:  # uvicorn's own loggers do not propagate to caplog's root handler
        logger.addHandler(caplog.handler)
        logger.setLevel(logging.INFO)
    try:
        async with connect(guarded.ws_url + f"/ws/skeletons?format=json&token={TOKEN}") as ws:
            await ws.recv()
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        async with httpx.AsyncClient(base_url=guarded.http_url, headers=bearer) as client:
            assert (await client.get(f"/api/persons?token={TOKEN}")).status_code == 200
            await client.get(f"/api/health?token={TOKEN}&x=1")
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.removeHandler(caplog.handler)
            logger.setLevel(level)
    assert TOKEN not in caplog.text
    assert "/ws/skeletons?format=json&token=***" in caplog.text  # the handshake line is there
    assert "/api/persons?token=***" in caplog.text  # and the access lines
    assert "/api/health?token=***&x=1" in caplog.text


def test_open_server_stays_open(live_server: LiveServer) -> None:
    response = httpx.post(live_server.http_url + "/api/calibration/runs", json={"method": "auto"})
    assert response.status_code == 409  # no token configured: only the missing sensors matter
