"""Request bodies over the limit get 413 before they are read, whether they say their length or not.

Issue 12: a chunked body (no Content-Length) was read in full and then parsed; 8 MiB got a 422 and
128 MiB took the server to 504 MB. These tests upload from outside over a raw socket, the way any
HTTP/1.1 client streams a body, and read the answer as soon as the server gives it
(``bench/live/body_limit.py``'s upload, which also prints the figures).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

from bench.live.body_limit import MiB, chunked_upload, reset_peak_rss, rss_bytes
from tests.conftest import PROJECT_ROOT
from tests.integration.conftest import LiveServer
from tests.support import free_port, wait_until

pytestmark = pytest.mark.timeout(90)
TOKEN = "body-limit-token"


def test_chunked_body_over_the_limit_gets_413_not_422(
    server_factory: Callable[..., LiveServer],
) -> None:
    live = server_factory(api_token=TOKEN)
    upload = chunked_upload(live.settings.http_port, "/api/calibration/import", 8 * MiB, TOKEN)
    assert upload.status == 413, upload
    assert "larger than 1048576 bytes" in json.loads(upload.body)["detail"]
    # The answer came while the client was still sending: the rest was never waited for.
    assert upload.sent_bytes < 8 * MiB


def test_chunked_body_under_the_limit_is_read(server_factory: Callable[..., LiveServer]) -> None:
    live = server_factory(api_token=TOKEN)
    upload = chunked_upload(live.settings.http_port, "/api/calibration/import", MiB - 1, TOKEN)
    # Read in full and parsed: a JSON array is not a calibration file (422), but not too large.
    assert upload.status == 422, upload
    assert upload.sent_bytes == MiB - 1


def test_declared_length_over_the_limit_gets_413_at_once(
    server_factory: Callable[..., LiveServer],
) -> None:
    live = server_factory(api_token=TOKEN)
    response = httpx.post(
        live.http_url + "/api/bones/default",
        content=b"{" + b" " * (2 * MiB) + b"}",
        headers={"Authorization": f"Bearer {TOKEN}", "content-type": "application/json"},
    )
    assert response.status_code == 413
    assert response.headers["connection"] == "close"


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
    before = rss_bytes(process.pid)
    reset_peak_rss(process.pid)  # VmHWM is then the peak during this upload alone
    upload = chunked_upload(port, "/api/calibration/import", 128 * MiB, TOKEN)
    peak = rss_bytes(process.pid, "VmHWM")
    assert upload.status == 413, upload
    assert peak - before < 5 * MiB, f"server RSS grew {(peak - before) / MiB:.1f} MiB"
    # Cut off after the limit and what the sockets buffer, far short of the 128 MiB offered.
    assert upload.sent_bytes < 32 * MiB, upload.sent_bytes
    assert process.poll() is None
