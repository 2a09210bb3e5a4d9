"""The demo's self-calibration client against a scripted REST server on loopback."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import pytest

from skelfuse.demo import calibrate


class ScriptedApi:
    """Answers the few routes calibrate() uses; each new run takes the next trust level."""

    def __init__(self, trusts: list[str]) -> None:
        self.trusts = trusts
        self.runs: list[dict[str, Any]] = []
        self.commits: list[str] = []

    def handle(self, method: str, path: str) -> tuple[int, object]:
        if method == "GET" and path == "/api/sensors":
            return 200, {"sensors": [{"id": "sim-1", "connected": True},
                                     {"id": "sim-2", "connected": True}]}  # fmt: skip
        if method == "POST" and path == "/api/calibration/runs":
            trust = self.trusts[len(self.runs)]
            run = {"id": f"r{len(self.runs)}", "state": "done", "stage": "", "progress": 1.0,
                   "results": {"sim-1": {"method": "reference", "residual_mm": 0.0,
                                         "warnings": [], "metrics": {}},
                               "sim-2": {"method": "skeleton+icp", "residual_mm": 20.0,
                                         "warnings": [], "metrics": {"trust": trust}}}}  # fmt: skip
            self.runs.append(run)
            return 202, run
        if method == "POST" and path.endswith("/commit"):
            self.commits.append(path.split("/")[-2])
            return 200, {"version": len(self.commits)}
        return 404, {"detail": "not scripted"}


@pytest.fixture
def api(request: pytest.FixtureRequest) -> Iterator[tuple[str, ScriptedApi]]:
    script = ScriptedApi(request.param)

    class Handler(BaseHTTPRequestHandler):
        def _answer(self, method: str) -> None:
            length = int(self.headers.get("Content-Length") or 0)
            self.rfile.read(length)
            status, body = script.handle(method, self.path)
            data = json.dumps(body).encode()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def do_GET(self) -> None:
            self._answer("GET")

        def do_POST(self) -> None:
            self._answer("POST")

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}", script
    server.shutdown()
    server.server_close()


@pytest.mark.parametrize("api", [["low", "high"]], indirect=True)
def test_a_doubtful_calibration_is_run_again_before_commit(api: tuple[str, ScriptedApi]) -> None:
    url, script = api
    assert calibrate(url, 2, threading.Event(), token="t")
    assert [run["id"] for run in script.runs] == ["r0", "r1"]
    assert script.commits == ["r1"], "only the trusted run is committed"


@pytest.mark.parametrize("api", [["low", "low", "low"]], indirect=True)
def test_the_last_attempt_is_committed_even_if_doubtful(api: tuple[str, ScriptedApi]) -> None:
    url, script = api
    assert calibrate(url, 2, threading.Event(), token="t", attempts=3)
    assert len(script.runs) == 3 and script.commits == ["r2"]
