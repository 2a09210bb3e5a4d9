"""A quiet terminal (issue 13 item 5): no access log unless asked, the demo's address in a box.

The whole demo on a terminal is tested in tests/e2e/test_demo.py; these pin the pieces fast.
"""

from __future__ import annotations

import logging

import pytest

from skelfuse.cli import build_parser
from skelfuse.cli.server import uvicorn_config
from skelfuse.demo import viewer_box
from tests.support_terminal import boxed_lines


@pytest.mark.parametrize(("flags", "logged"), [((), False), (("--access-log",), True)])
def test_the_server_logs_requests_only_with_access_log(
    flags: tuple[str, ...], logged: bool
) -> None:
    args = build_parser().parse_args(["server", *flags])
    config = uvicorn_config(object(), "127.0.0.1", 8000, "info", False, access_log=args.access_log)
    assert config.access_log is logged


@pytest.mark.parametrize(("flags", "on"), [((), False), (("--access-log",), True)])
def test_the_demo_passes_access_log_on(flags: tuple[str, ...], on: bool) -> None:
    args = build_parser().parse_args(["demo", *flags])
    assert args.access_log is on
    assert args.recalibrate is False


def test_the_box_holds_the_whole_address_on_a_terminal_only() -> None:
    url, token = "http://127.0.0.1:8000", "-abc_DEF123xyz45"
    shown = viewer_box(url, token, "the token in /d/api-token", terminal=True)
    lines = shown.splitlines()
    assert len({len(line) for line in lines}) == 1, shown  # a closed rectangle
    assert boxed_lines(shown) == [
        ["skelfuse demo is fusing; open the viewer (Ctrl-C stops):", f"{url}/?token={token}"]
    ]
    logged = viewer_box(url, token, "the token in /d/api-token", terminal=False)
    assert token not in logged
    assert f"{url}/?token=<the token in /d/api-token>" in logged


@pytest.mark.parametrize("access_log", [False, True])
def test_websocket_connection_lines_follow_the_access_log(access_log: bool) -> None:
    """uvicorn logs each WebSocket connection on its error log, whatever its access log says:
    three lines per viewer that connects, off with the access log."""
    uvicorn_config(object(), "127.0.0.1", 8000, "info", False, access_log=access_log)
    error_log = logging.getLogger("uvicorn.error")

    def kept(message: str, *args: object) -> bool:
        record = error_log.makeRecord("uvicorn.error", logging.INFO, "", 0, message, args, None)
        return bool(error_log.filter(record))

    assert kept('%s - "WebSocket %s" [accepted]', "127.0.0.1:5", "/ws/skeletons") is access_log
    assert kept('%s - "WebSocket %s" 403', "127.0.0.1:5", "/ws/skeletons") is access_log
    assert kept("connection open") is access_log
    assert kept("connection closed") is access_log
    assert kept("Application startup complete.")  # everything else stays
