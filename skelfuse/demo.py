"""``skelfuse demo``: the fusion server and N simulated Kinects as separate processes.

Everything talks over real sockets exactly as on a real rig: agents -> ZeroMQ -> server ->
WebSocket -> viewer. Sensors stand evenly around the room looking at the performers.

Calibration (default ``auto``): the demo calibrates itself through the REST API exactly as a
user would with curl (README): start an ``auto`` run while the simulated people walk, wait,
commit. With ``truth`` the agents instead tell the server their true poses (``pose_hint`` with
source ``sim_truth``). A ``--data`` folder that already holds a calibration of every sensor is
used as it is (``recalibrate`` to calibrate again).

Once fusion runs, the viewer's address is the last thing on the terminal, in a box.
"""

from __future__ import annotations

import json
import logging
import math
import os
import secrets
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from skelfuse.parent_watch import child_environment
from skelfuse.server.auth import KeysMissing, create_agent_keys, create_server_keys, key_paths

logger = logging.getLogger("skelfuse.demo")

SENSOR_RING_RADIUS_M = 3.0
SENSOR_HEIGHT_M = 1.0
SENSOR_PITCH_DEG = 5.0


def sensor_layout(count: int) -> list[tuple[str, str]]:
    """(sensor id, pose argument) for ``count`` sensors evenly around the origin."""
    layout = []
    for i in range(count):
        angle = math.radians(360.0 * i / count + 15.0)
        x = SENSOR_RING_RADIUS_M * math.sin(angle)
        z = SENSOR_RING_RADIUS_M * math.cos(angle)
        yaw = (math.degrees(angle) + 360.0) % 360.0 - 180.0  # look back at the origin
        layout.append(
            (f"sim-{i + 1}", f"{x:.3f},{SENSOR_HEIGHT_M},{z:.3f},{yaw:.2f},{SENSOR_PITCH_DEG}")
        )
    return layout


_SERVER_START_S = 120.0
"""How long the server may take to answer: its first start compiles the fusion kernels (~25 s
on an idle 2-core machine, more while pip or the agents load it), later ones take ~1 s."""


def _wait_healthy(
    url: str, server: subprocess.Popen[bytes], stop: threading.Event, timeout_s: float
) -> bool:
    """Whether the server answers healthy within ``timeout_s``; False once it exits or the demo
    is stopped (Ctrl-C) meanwhile."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not stop.is_set():
        if server.poll() is not None:
            return False
        try:
            with urllib.request.urlopen(url + "/api/health", timeout=1.0) as response:
                if json.load(response).get("status") == "ok":
                    return True
        except (urllib.error.URLError, OSError, ValueError):
            pass
        stop.wait(0.2)
    return False


def _api(
    url: str, method: str = "GET", body: dict[str, Any] | None = None, token: str | None = None
) -> Any:
    data = None if body is None else json.dumps(body).encode()
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    request = urllib.request.Request(url, data=data, method=method, headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return json.load(response)
    except urllib.error.HTTPError as exc:
        detail = exc.read().decode(errors="replace")
        raise RuntimeError(f"{method} {url}: HTTP {exc.code}: {detail}") from exc


def calibrate(
    url: str, sensors: int, stop: threading.Event, token: str | None = None, attempts: int = 3
) -> bool:
    """Wait for the agents, run ``auto`` calibration and commit it; True on success."""
    deadline = time.monotonic() + 60
    while not stop.is_set():
        rows = _api(url + "/api/sensors")["sensors"]
        if sum(r["connected"] for r in rows) == sensors:
            break
        if time.monotonic() > deadline:
            logger.error("only %d of %d sensors connected after 60 s", len(rows), sensors)
            return False
        stop.wait(0.5)
    for attempt in range(1, attempts + 1):
        if stop.is_set():
            return False
        logger.info("calibrating (auto: skeleton while the people walk, then ICP on depth, "
                    "then the floor); attempt %d of %d", attempt, attempts)  # fmt: skip
        run = _api(url + "/api/calibration/runs", "POST", {"method": "auto"}, token)
        last_stage = ""
        while run["state"] in ("capturing", "solving") and not stop.is_set():
            if run["stage"] != last_stage:
                last_stage = run["stage"]
                logger.info("calibration: %s (%.0f%%)", last_stage, run["progress"] * 100)
            stop.wait(0.5)
            run = _api(f"{url}/api/calibration/runs/{run['id']}")
        doubtful = sorted(
            sensor_id
            for sensor_id, result in (run.get("results") or {}).items()
            if (result.get("metrics") or {}).get("trust") == "low"
        )
        if run["state"] == "done" and doubtful and attempt < attempts:
            # As a user would: the people did not walk enough in this window; try again.
            logger.warning("calibration of %s is doubtful (low trust); running it again",
                           ", ".join(doubtful))  # fmt: skip
            continue
        if run["state"] == "done":
            committed = _api(f"{url}/api/calibration/runs/{run['id']}/commit", "POST", {}, token)
            for sensor_id, result in sorted(run["results"].items()):
                logger.info(
                    "  %s: %s, residual %s mm%s",
                    sensor_id,
                    result["method"],
                    result["residual_mm"],
                    f" ({'; '.join(result['warnings'])})" if result["warnings"] else "",
                )
            logger.info("calibration v%d committed; fusing", committed["version"])
            return True
        logger.warning("calibration failed: %s", run.get("error"))
    return False


def _terminate(processes: list[subprocess.Popen[bytes]], timeout_s: float = 5.0) -> None:
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout_s
    for process in processes:
        try:
            process.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _token_location(token: str, *, chosen: bool, data_dir: Path) -> str:
    """Where the token is, in words: the user's own, or a random one saved owner-only."""
    if chosen:
        return "your --token"
    token_file = data_dir / "api-token"
    token_file.write_text(token + "\n", encoding="utf-8")
    token_file.chmod(0o600)
    return f"the token in {token_file}"


def _announce_viewer(url: str, where: str) -> None:
    """Log, without the token itself, where the viewer is and where its token is.

    Logs end up in files, journals and CI output (issue 12: no secret in any log line); the
    whole address goes to the terminal only (:func:`viewer_box`).
    """
    # Worded so that nothing here looks like a secret to the log's masking (token=…, Bearer …).
    logger.info(
        "open the viewer at %s/?token= followed by %s  (REST docs at %s/docs; changes send the "
        "token as a Bearer authorization header) - Ctrl-C to stop",
        url,
        where,
        url,
    )


def viewer_box(url: str, token: str, where: str, *, terminal: bool) -> str:
    """The viewer's address in a box, for the last lines of the demo's terminal.

    Args:
        url: the server's base address (``http://host:port``).
        token: the API token; shown only when ``terminal`` (a person is watching), because
            output that is not a terminal usually ends up in a file or a CI log.
        where: where the token is, in words (:func:`_token_location`), for the other case.
        terminal: the box goes to an interactive terminal.
    """
    address = f"{url}/?token={token}" if terminal else f"{url}/?token=<{where}>"
    lines = ["skelfuse demo is fusing; open the viewer (Ctrl-C stops):", address]
    width = max(len(line) for line in lines)
    rule = "+" + "-" * (width + 2) + "+"
    return "\n".join([rule, *(f"| {line:<{width}} |" for line in lines), rule])


def _wait_fusing(url: str, sensors: int, stop: threading.Event, timeout_s: float) -> bool:
    """Wait until every sensor is online and the server fuses people (``/api/health``);
    False on timeout or stop."""
    deadline = time.monotonic() + timeout_s
    while not stop.is_set() and time.monotonic() < deadline:
        try:
            health = _api(url + "/api/health")
            if health["sensors_online"] >= sensors and int(health["persons"]) > 0:
                return True
        except (RuntimeError, OSError, ValueError, KeyError):
            pass
        stop.wait(0.25)
    return False


def _kept_calibration(url: str, sensor_ids: list[str]) -> int | None:
    """The version of the server's stored calibration if it covers every sensor, else None."""
    active = _api(url + "/api/calibration")
    if active.get("version") is None or not set(sensor_ids) <= set(active.get("sensors") or ()):
        return None
    return int(active["version"])


def run_demo(
    *,
    sensors: int = 3,
    persons: int = 2,
    http: tuple[str, int] = ("127.0.0.1", 8000),
    zmq_port: int = 5555,
    data_dir: Path | None = None,
    duration_s: float | None = None,
    log_level: str = "INFO",
    calibration: str = "auto",
    token: str | None = None,
    recalibrate: bool = False,
    access_log: bool = False,
) -> int:
    """Run until Ctrl-C (or ``duration_s``); returns the exit status.

    ``recalibrate``: calibrate (``auto``) even when ``data_dir`` holds a calibration of every
    sensor. ``access_log``: the server logs every HTTP request.
    """
    if not 1 <= sensors <= 8:
        logger.error("--sensors must be 1..8")
        return 2
    if not 1 <= persons <= 6:
        logger.error("--persons must be 1..6")
        return 2
    host, port = http
    temporary = None
    if data_dir is None:
        temporary = tempfile.TemporaryDirectory(prefix="skelfuse-demo-")
        data_dir = Path(temporary.name)
    agent_host = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    # Secure like a real rig: every simulated agent gets its own CurveZMQ key (docs/security.md).
    layout = sensor_layout(sensors)
    token_given = token is not None
    token = token or secrets.token_urlsafe(12)
    agent_keys = _agent_secret_keys(data_dir, layout)
    if agent_keys is None:
        return 2
    server = _start_server(log_level, host, port, zmq_port, data_dir, token, access_log)
    processes: list[subprocess.Popen[bytes]] = [server]
    stop = threading.Event()
    previous = _stop_on_signals(stop)
    url = f"http://{agent_host}:{port}"
    try:
        if not _wait_healthy(url, server, stop, timeout_s=_SERVER_START_S):
            return 0 if stop.is_set() else _server_failed(server, url, port, zmq_port)
        server_endpoint = f"tcp://{agent_host}:{zmq_port}"
        no_pose_hint = calibration == "auto"
        for sensor_id, pose in layout:
            agent = _agent_command(
                log_level, sensor_id, pose, persons, server_endpoint, no_pose_hint,
                agent_keys[sensor_id], key_paths(data_dir).server_public,
            )  # fmt: skip
            processes.append(subprocess.Popen(agent, env=child_environment(), **_own_group()))
        logger.info("demo running: %d simulated sensors, %d people", sensors, persons)
        where = _token_location(token, chosen=token_given, data_dir=data_dir)
        _announce_viewer(url, where)
        deadline = None if duration_s is None else time.monotonic() + duration_s
        failed = _calibration_failed(url, layout, stop, token, calibration, recalibrate, data_dir)
        if failed is not None:
            return failed
        wait_s = 60.0 if deadline is None else min(60.0, max(0.0, deadline - time.monotonic()))
        if not _wait_fusing(url, sensors, stop, timeout_s=wait_s) and not stop.is_set():
            logger.warning("no fused people after %.0f s; the viewer may stay empty", wait_s)
        if not stop.is_set():
            terminal = sys.stderr.isatty()  # a person is watching: the address, to click
            print(viewer_box(url, token, where, terminal=terminal), file=sys.stderr, flush=True)
        return _watch(processes, stop, deadline)
    finally:
        # Agents first (they say bye), then the server.
        _terminate(processes[1:])
        _terminate([server])
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if temporary is not None:
            temporary.cleanup()
        logger.info("demo stopped")


def _calibration_failed(
    url: str,
    layout: list[tuple[str, str]],
    stop: threading.Event,
    token: str,
    calibration: str,
    recalibrate: bool,
    data_dir: Path,
) -> int | None:
    """Keep the server's stored calibration if it covers every sensor (unless ``recalibrate``),
    else calibrate when ``calibration`` is ``auto``. None when the demo goes on, else its exit
    status (0 when stopped meanwhile, 1 when the calibration failed)."""
    kept = None if recalibrate else _kept_calibration(url, [s for s, _ in layout])
    if kept is not None:
        logger.info("using calibration v%d kept in %s (--recalibrate to calibrate again)",
                    kept, data_dir)  # fmt: skip
    elif calibration == "auto" and not calibrate(url, len(layout), stop, token):
        if stop.is_set():
            return 0
        logger.error("automatic calibration failed; try --calibration truth")
        return 1
    return None


def _own_group() -> dict[str, Any]:
    """``Popen`` options that put a child in its own process group (on POSIX)."""
    # The children get their own process group: Ctrl-C in a terminal signals the whole
    # foreground group, and a server signalled twice (by the terminal, then by the demo's own
    # orderly stop) aborts its shutdown with a traceback. The demo alone stops them.
    return {"process_group": 0} if os.name == "posix" else {}


def _start_server(
    log_level: str,
    host: str,
    port: int,
    zmq_port: int,
    data_dir: Path,
    token: str,
    access_log: bool,
) -> subprocess.Popen[bytes]:
    """``skelfuse server`` in a child process, with CurveZMQ and ``token``, on ``host``."""
    python = [sys.executable, "-m", "skelfuse", "--log-level", log_level]
    zmq_bind = (
        f"tcp://{host}:{zmq_port}" if host not in ("0.0.0.0", "::") else f"tcp://*:{zmq_port}"
    )
    # A demo killed outright (SIGKILL) runs no cleanup: each child watches this process and
    # stops itself once it is gone (skelfuse.parent_watch), instead of running on for hours.
    return subprocess.Popen(
        [
            *python, "server", "--http", f"{host}:{port}", "--zmq", zmq_bind,
            "--data", str(data_dir), "--curve", *(["--access-log"] if access_log else []),
        ],
        # The token goes in the environment: a command line is readable by every local user.
        env={**child_environment(), "SKELFUSE_TOKEN": token},
        **_own_group(),
    )  # fmt: skip


def _agent_command(
    log_level: str,
    sensor_id: str,
    pose: str,
    persons: int,
    server: str,
    no_pose_hint: bool,
    key: Path,
    server_key: Path,
) -> list[str]:
    """A simulated agent's command line: ``sensor_id`` at ``pose`` (x,y,z,yaw,pitch), connecting
    to the ``server`` endpoint with its secret ``key`` and the server's public key."""
    # The agents' INFO lines are a statistic every 10 s each: they would push the viewer's
    # address (the last thing the demo prints) off the screen. Their warnings still show.
    quiet = "DEBUG" if log_level.upper() == "DEBUG" else "WARNING"
    return [
        sys.executable, "-m", "skelfuse", "--log-level", quiet,
        "agent", "--source", "sim", "--id", sensor_id, f"--pose={pose}",
        "--persons", str(persons), "--server", server,
        *(["--no-pose-hint"] if no_pose_hint else []),
        f"--key={key}", f"--server-key={server_key}",
    ]  # fmt: skip


def _agent_secret_keys(data_dir: Path, layout: list[tuple[str, str]]) -> dict[str, Path] | None:
    """The server's keys and each simulated agent's secret key file in ``data_dir``, made if
    missing; None (the reason logged) when they cannot be had."""
    try:  # a --data folder from an earlier run keeps its keys
        create_server_keys(data_dir)
        agent_keys = {sensor_id: create_agent_keys(data_dir, sensor_id).secret
                      for sensor_id, _ in layout}  # fmt: skip
    except KeysMissing as exc:
        logger.error("%s", exc)
        return None
    missing = [str(path) for path in agent_keys.values() if not path.exists()]
    if missing:
        logger.error("the simulated agents' secret keys are missing: %s", ", ".join(missing))
        return None
    return agent_keys


def _stop_on_signals(stop: threading.Event) -> dict[int, Any]:
    """Set ``stop`` on SIGINT, SIGTERM and SIGHUP; returns the handlers replaced (to restore)."""

    def on_signal(signum: int, frame: object) -> None:
        stop.set()

    # SIGHUP too (the terminal closed): the children, in their own group, would outlive it.
    stop_signals = [signal.SIGINT, signal.SIGTERM]
    if hasattr(signal, "SIGHUP"):
        stop_signals.append(signal.SIGHUP)
    return {s: signal.signal(s, on_signal) for s in stop_signals}


def _server_failed(server: subprocess.Popen[bytes], url: str, port: int, zmq_port: int) -> int:
    """Say why the server is not ready (it exited, or did not answer); the exit status, 1."""
    if server.poll() is not None:
        logger.error(
            "the server exited with code %s before it was ready (its message is above; "
            "a port in use, %d or %d, is a common cause)",
            server.returncode,
            port,
            zmq_port,
        )
    else:
        logger.error("the server did not answer on %s within %.0f s", url, _SERVER_START_S)
    return 1


def _watch(
    processes: list[subprocess.Popen[bytes]], stop: threading.Event, deadline: float | None
) -> int:
    """Run until ``stop``, the ``deadline`` (monotonic seconds) or a process's exit; the exit
    status: 1 when a process exited, else 0."""
    while not stop.is_set():
        if deadline is not None and time.monotonic() >= deadline:
            break
        dead = [p for p in processes if p.poll() is not None]
        if dead:
            logger.error(
                "a demo process exited unexpectedly (%s); stopping",
                dead[0].args,
            )
            return 1
        stop.wait(0.5)
    return 0
