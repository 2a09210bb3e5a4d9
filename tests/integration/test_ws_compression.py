"""permessage-deflate on the feed: off unless ``skelfuse server --ws-compression`` (issue 11).

The server is uvicorn configured exactly as ``skelfuse server`` configures it
(``skelfuse.cli.server.uvicorn_config``, from the real command line's parsed arguments); the
client is the websockets library, which offers permessage-deflate in every handshake, as
browsers do.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import uvicorn
from websockets.asyncio.client import connect

from skelfuse.cli import build_parser
from skelfuse.cli.server import uvicorn_config
from skelfuse.server.app import create_app
from skelfuse.server.settings import Settings
from tests.support import free_port


def _serve(tmp_path: Path, *cli_flags: str) -> Iterator[str]:
    """Run the server as ``skelfuse server [cli_flags]`` would, in a thread; yields its ws URL."""
    http_port, zmq_port = free_port(), free_port()
    args = build_parser().parse_args(["server", *cli_flags])
    settings = Settings(
        http_host="127.0.0.1", http_port=http_port,
        zmq_endpoint=f"tcp://127.0.0.1:{zmq_port}", data_dir=tmp_path / "data",
    )  # fmt: skip
    config = uvicorn_config(
        create_app(settings), "127.0.0.1", http_port, "warning", args.ws_compression
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 15
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "uvicorn did not start"
        time.sleep(0.02)
    try:
        yield f"ws://127.0.0.1:{http_port}/ws/skeletons"
    finally:
        server.should_exit = True
        thread.join(timeout=10)


@pytest.fixture
def default_server(tmp_path: Path) -> Iterator[str]:
    yield from _serve(tmp_path)


@pytest.fixture
def compressing_server(tmp_path: Path) -> Iterator[str]:
    yield from _serve(tmp_path, "--ws-compression")


async def _handshake_extensions(url: str) -> str | None:
    """What the server answered to a client offering permessage-deflate; the greeting arrives."""
    async with connect(url, compression="deflate") as ws:
        assert json.loads(await ws.recv())["type"] == "skeleton"
        assert ws.response is not None
        extensions: str | None = ws.response.headers.get("Sec-WebSocket-Extensions")
        return extensions


async def test_the_feed_is_not_compressed_by_default(default_server: str) -> None:
    assert await _handshake_extensions(default_server) is None


async def test_ws_compression_negotiates_permessage_deflate(compressing_server: str) -> None:
    extensions = await _handshake_extensions(compressing_server)
    assert extensions is not None and "permessage-deflate" in extensions
