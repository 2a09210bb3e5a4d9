"""Request bodies over the limit get 413 before they are read, whether they say their length or not.

Issue 12: a chunked body (no Content-Length) was read in full and then parsed; 8 MiB got a 422 and
128 MiB took the server to 504 MB. These tests upload from outside over a raw socket, the way any
HTTP/1.1 client streams a body, and read the answer as soon as the server gives it.
"""

from __future__ import annotations

import json
import select
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from tests.conftest import PROJECT_ROOT
from tests.integration.conftest import LiveServer
from tests.support import free_port, wait_until

pytestmark = pytest.mark.timeout(90)
TOKEN = "body-limit-token"
MiB = 1024 * 1024
CHUNK = 64 * 1024


@dataclass(frozen=True)
class Upload:
    status: int
    """The HTTP status the server answered with (0: none before the connection ended)."""
    body: bytes
    sent_bytes: int
    """Body bytes the client managed to hand to its socket before the server answered."""


def chunked_upload(port: int, path: str, total_bytes: int, token: str | None = None) -> Upload:
    """POST ``total_bytes`` of JSON-ish body with ``Transfer-Encoding: chunked``, 64 KiB a chunk,
    stopping as soon as the server answers (or drops the connection)."""
    head = (
        f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
        "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n"
        + (f"Authorization: Bearer {token}\r\n" if token else "")
        + "\r\n"
    ).encode()
    payload = b"[" + b"0," * (CHUNK // 2 - 1) + b"0"  # valid JSON if it were ever closed
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(head)
        try:
            while sent < total_bytes:
                readable, _, _ = select.select([sock], [], [], 0)
                if readable:  # the server answered early: stop sending, as HTTP/1.1 clients do
                    break
                data = payload[: min(CHUNK, total_bytes - sent)]
                sock.sendall(b"%x\r\n%s\r\n" % (len(data), data))
                sent += len(data)
            else:
                sock.sendall(b"0\r\n\r\n")
        except (BrokenPipeError, ConnectionResetError):
            pass
        response = b""
        try:
            while chunk := sock.recv(65536):
                response += chunk
                if b"\r\n\r\n" in response and _complete(response):
                    break
        except (ConnectionResetError, TimeoutError):
            pass
    if not response.startswith(b"HTTP/1.1 "):
        return Upload(0, b"", sent)
    head_bytes, _, body = response.partition(b"\r\n\r\n")
    return Upload(int(head_bytes.split()[1]), body, sent)


def _complete(response: bytes) -> bool:
    head, _, body = response.partition(b"\r\n\r\n")
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(body) >= int(value)
    return False


def test_chunked_body_over_the_limit_gets_413_not_422(server_factory: object) -> None:
    live: LiveServer = server_factory(api_token=TOKEN)  # type: ignore[operator]
    upload = chunked_upload(live.settings.http_port, "/api/calibration/import", 8 * MiB, TOKEN)
    assert upload.status == 413, upload
    assert "larger than 1048576 bytes" in json.loads(upload.body)["detail"]
    # The answer came while the client was still sending: the rest was never waited for.
    assert upload.sent_bytes < 8 * MiB


def test_chunked_body_under_the_limit_is_read(server_factory: object) -> None:
    live: LiveServer = server_factory(api_token=TOKEN)  # type: ignore[operator]
    upload = chunked_upload(live.settings.http_port, "/api/calibration/import", MiB - 1, TOKEN)
    # Read in full and parsed: a JSON array is not a calibration file (422), but not too large.
    assert upload.status == 422, upload
    assert upload.sent_bytes == MiB - 1


def test_declared_length_over_the_limit_gets_413_at_once(server_factory: object) -> None:
    live: LiveServer = server_factory(api_token=TOKEN)  # type: ignore[operator]
    response = httpx.post(
        live.http_url + "/api/bones/default",
        content=b"{" + b" " * (2 * MiB) + b"}",
        headers={"Authorization": f"Bearer {TOKEN}", "content-type": "application/json"},
    )
    assert response.status_code == 413
    assert response.headers["connection"] == "close"


def _rss_bytes(pid: int, field: str = "VmRSS") -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"{field} not in /proc/{pid}/status")


@pytest.fixture
def server_process(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], int]]:
    """``skelfuse server`` as its own process, so its memory can be read from /proc."""
    port = free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "skelfuse", "--log-level", "WARNING", "server",
         "--http", f"127.0.0.1:{port}", "--zmq", f"tcp://127.0.0.1:{free_port()}",
         "--data", str(tmp_path / "data"), f"--token={TOKEN}"],
        cwd=PROJECT_ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        url = f"http://127.0.0.1:{port}/api/health"
        assert wait_until(lambda: httpx.get(url).status_code == 200, timeout_s=60)
        yield process, port
    finally:
        process.terminate()
        process.wait(timeout=20)


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads RSS from /proc")
def test_a_128_mib_chunked_upload_leaves_server_memory_flat(
    server_process: tuple[subprocess.Popen[bytes], int],
) -> None:
    process, port = server_process
    chunked_upload(port, "/api/calibration/import", 64 * 1024, TOKEN)  # warm the route up
    time.sleep(0.2)
    before = _rss_bytes(process.pid)
    # Reset the peak ("high water mark") so VmHWM is the peak during this upload alone.
    Path(f"/proc/{process.pid}/clear_refs").write_text("5")
    upload = chunked_upload(port, "/api/calibration/import", 128 * MiB, TOKEN)
    peak = _rss_bytes(process.pid, "VmHWM")
    assert upload.status == 413, upload
    assert peak - before < 5 * MiB, f"server RSS grew {(peak - before) / MiB:.1f} MiB"
    # Cut off after the limit and what the sockets buffer, far short of the 128 MiB offered.
    assert upload.sent_bytes < 32 * MiB, upload.sent_bytes
    assert process.poll() is None
