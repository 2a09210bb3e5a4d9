"""The server under test: a subprocess on loopback, polled over HTTP, measured in /proc.

``SKELFUSE_LOAD_FUSION_CONFIG``: a TOML file handed to the server as ``--fusion-config``, to
measure settings other than the defaults (e.g. ``[fusion] alignment = "deadline"``, issue 11
item 1) with the same command.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from skelfuse.calibration.store import CalibrationStore, SensorCalibration
from skelfuse.parent_watch import child_environment
from skelfuse.protocol.transform import Matrix4

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    """A TCP port on loopback that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def http_json(url: str, timeout_s: float = 5.0) -> Any:
    """GET ``url`` and decode its JSON body."""
    with urllib.request.urlopen(url, timeout=timeout_s) as response:
        return json.load(response)


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (Linux ``/proc/<pid>/stat``)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_rss_mb(pid: int) -> float:
    """Resident set size in MB (Linux ``/proc/<pid>/statm``)."""
    pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def start_server(
    poses: dict[str, Matrix4], http_port: int, zmq_port: int, log_path: Path
) -> tuple[subprocess.Popen[bytes], IO[bytes]]:
    """``python -m skelfuse server`` on loopback, with a stored calibration for ``poses``."""
    data_dir = Path(tempfile.mkdtemp(prefix="skelfuse-load-"))
    CalibrationStore(data_dir).save(
        {s: SensorCalibration(pose, "bench") for s, pose in poses.items()},
        note="bench/live/load.py",
    )
    log_file = log_path.open("wb")
    fusion_config = os.environ.get("SKELFUSE_LOAD_FUSION_CONFIG")
    server = subprocess.Popen(
        [sys.executable, "-m", "skelfuse", "--log-level", "WARNING", "server",
         "--http", f"127.0.0.1:{http_port}", "--zmq", f"tcp://127.0.0.1:{zmq_port}",
         "--data", str(data_dir),
         *(["--fusion-config", fusion_config] if fusion_config else [])],
        stdout=log_file, stderr=subprocess.STDOUT, cwd=ROOT,
        env=child_environment(),  # a benchmark killed outright takes its server with it
    )  # fmt: skip
    return server, log_file


async def get(url: str) -> Any:
    """``http_json`` off the event loop."""
    return await asyncio.to_thread(http_json, url)


def wait_for(predicate: Callable[[], object], timeout_s: float, what: str) -> None:
    """Poll ``predicate`` every 0.1 s until it is true; an exception counts as not yet.

    Raises:
        RuntimeError: still not true after ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    last: Exception | None = None
    while time.monotonic() < deadline:
        try:
            if predicate():
                return
        except Exception as exc:  # not up yet
            last = exc
        time.sleep(0.1)
    raise RuntimeError(f"timed out after {timeout_s:.0f} s waiting for {what} ({last})")
