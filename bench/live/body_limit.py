"""A chunked upload far over the body limit must not grow the server (issue 12 #4).

Starts a server process on loopback (the real app under uvicorn, with a token), warms its route
up, resets the process's peak RSS (``/proc/<pid>/clear_refs``), streams ``--mib`` MiB to
``POST /api/calibration/import`` with ``Transfer-Encoding: chunked`` over a raw socket (no
Content-Length), stopping as soon as the server answers, and prints the server's peak RSS growth,
the status and how much the client got to send. Linux only (``/proc``)::

    .venv/bin/python -m bench body_limit                 # 128 MiB, 3 repeats, fresh servers
    .venv/bin/python -m bench body_limit --no-limit      # the app without server/body_limit.py

``--no-limit`` removes the :class:`~skelfuse.server.body_limit.BodyLimit` middleware, which is
the server as it was before (it read the whole chunked body, then parsed it: 422).
``tests/integration/test_body_limit.py`` asserts the bound with the same upload.
"""

from __future__ import annotations

import argparse
import select
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import httpx

MiB = 1024 * 1024
CHUNK = 64 * 1024
TOKEN = "bench-token"
_SERVE = """
import sys
from pathlib import Path
import uvicorn
from skelfuse.server.app import create_app
from skelfuse.server.settings import Settings
port, zmq_port, data, limit = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4] == "1"
settings = Settings(http_port=port, zmq_endpoint=f"tcp://127.0.0.1:{zmq_port}",
                    data_dir=Path(data), api_token=sys.argv[5])
app = create_app(settings)
if not limit:
    app.user_middleware = [m for m in app.user_middleware if m.cls.__name__ != "BodyLimit"]
uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")).run()
"""


@dataclass(frozen=True)
class Upload:
    status: int
    """The HTTP status the server answered with (0: none before the connection ended)."""
    body: bytes
    sent_bytes: int
    """Body bytes the client handed to its socket before the server answered."""


def chunked_upload(port: int, path: str, total_bytes: int, token: str | None = None) -> Upload:
    """POST ``total_bytes`` of JSON-ish body with ``Transfer-Encoding: chunked``, 64 KiB a chunk,
    stopping as soon as the server answers (as HTTP/1.1 clients do) or drops the connection."""
    head = (
        f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
        "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n"
        + (f"Authorization: Bearer {token}\r\n" if token else "")
        + "\r\n"
    ).encode()
    payload = b"[" + b"0," * (CHUNK // 2 - 1) + b"0"  # a JSON array, were it ever closed
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(head)
        try:
            while sent < total_bytes:
                readable, _, _ = select.select([sock], [], [], 0)
                if readable:  # the server answered early: stop sending
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
                if _complete(response):
                    break
        except (ConnectionResetError, TimeoutError):
            pass
    if not response.startswith(b"HTTP/1.1 "):
        return Upload(0, b"", sent)
    head_bytes, _, body = response.partition(b"\r\n\r\n")
    return Upload(int(head_bytes.split()[1]), body, sent)


def _complete(response: bytes) -> bool:
    head, separator, body = response.partition(b"\r\n\r\n")
    if not separator:
        return False
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(body) >= int(value)
    return False


def rss_bytes(pid: int, field: str = "VmRSS") -> int:
    """A process's resident set (``VmRSS``) or its peak since the last reset (``VmHWM``), bytes.

    Raises:
        KeyError: ``field`` is not in ``/proc/<pid>/status``.
    """
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(field)


def reset_peak_rss(pid: int) -> None:
    """Make ``VmHWM`` start again from the current RSS (Linux ≥ 4.0)."""
    Path(f"/proc/{pid}/clear_refs").write_text("5")


@dataclass(frozen=True)
class Result:
    growth_bytes: int
    upload: Upload
    seconds: float


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def measure(total_bytes: int, limit: bool) -> Result:
    """One fresh server process, one warm-up, one chunked upload of ``total_bytes``."""
    port = _free_port()
    with tempfile.TemporaryDirectory() as data:
        args = [str(port), str(_free_port()), data, "1" if limit else "0", TOKEN]
        server = subprocess.Popen([sys.executable, "-c", _SERVE, *args])
        try:
            deadline = time.monotonic() + 60
            while True:
                try:
                    httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=2)
                    break
                except httpx.HTTPError:
                    if time.monotonic() > deadline or server.poll() is not None:
                        raise RuntimeError("the server did not start") from None
                    time.sleep(0.1)
            chunked_upload(port, "/api/calibration/import", 64 * 1024, TOKEN)  # warm up
            time.sleep(0.2)
            before = rss_bytes(server.pid)
            reset_peak_rss(server.pid)
            start = time.perf_counter()
            upload = chunked_upload(port, "/api/calibration/import", total_bytes, TOKEN)
            seconds = time.perf_counter() - start
            return Result(rss_bytes(server.pid, "VmHWM") - before, upload, seconds)
        finally:
            server.terminate()
            server.wait(timeout=20)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--mib", type=int, default=128, help="upload size (default 128)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-limit", action="store_true", help="without BodyLimit (before)")
    args = parser.parse_args(argv)
    results = [measure(args.mib * MiB, not args.no_limit) for _ in range(args.repeat)]
    for r in results:
        print(
            f"status {r.upload.status}  server RSS +{r.growth_bytes / MiB:.1f} MiB  "
            f"client sent {r.upload.sent_bytes / MiB:.1f} MiB in {r.seconds:.2f} s"
        )
    growth = statistics.median(r.growth_bytes for r in results) / MiB
    print(f"median server RSS growth {growth:.1f} MiB over {len(results)} runs")
