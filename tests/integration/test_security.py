"""HTTP-side protection on a real server: token, browser origins, body size."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

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


def test_open_server_stays_open(live_server: LiveServer) -> None:
    response = httpx.post(live_server.http_url + "/api/calibration/runs", json={"method": "auto"})
    assert response.status_code == 409  # no token configured: only the missing sensors matter
