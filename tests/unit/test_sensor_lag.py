"""A sensor's clock lag from the calibration (``lag_s``, calibration/motion_sync.py) moves its
frames on the server's timeline, with injected clocks: stored at registration, changed at run
time by a new calibration (the frames already buffered move with it), absent = 0."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.calibration.store import Calibration, SensorCalibration
from skelfuse.fusion.sensors import calibrated_lag_s
from skelfuse.protocol.wire import Frame, Heartbeat, Hello, Welcome, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings

T0 = 1_800_000_000.0  # server wall clock at the start (Unix seconds)
OFFSET = 2.5  # the agent's clock runs 2.5 s behind the server's


def calibration(lags: dict[str, float | None], version: int = 1) -> Calibration:
    sensors = {s: SensorCalibration(np.eye(4), "test", lag_s=lag) for s, lag in lags.items()}
    return Calibration(version, T0, sensors)


def streamed(hub: FusionHub, seconds: float = 1.0, start: float = 0.0) -> None:
    """``cam`` on connection b"a": frames at 30 fps stamped 40 ms after what they show (their
    content is of server time t, their stamp the agent's clock at t + 0.04), and heartbeat
    echoes with the agent's true clock (so the round-trip offset does not absorb the lag)."""
    for i in range(round(seconds * 30)):
        t = start + i / 30
        stamp = round((T0 + t + 0.04 - OFFSET) * 1e9)
        seq = round(t * 30) + 1
        hub.handle_message(b"a", [encode(Frame(seq, stamp, ()))], T0 + t + 0.05, t)
        if i % 10 == 0:  # an echo of a server heartbeat sent 2 ms earlier
            echo = Heartbeat(round((T0 + t - OFFSET - 0.001) * 1e9), round((T0 + t - 0.002) * 1e9))
            hub.handle_message(b"a", [encode(echo)], T0 + t, t)


def registered(calibrated: Calibration | None) -> FusionHub:
    hub = FusionHub(Settings(heartbeat_interval_s=1.0), calibrated)
    reply = hub.handle_message(b"a", [encode(Hello("cam", "rgb", "t", 30.0, 0))], T0, 0.0)
    assert isinstance(reply[0], Welcome)
    return hub


def placed_lateness(hub: FusionHub) -> list[float]:
    """Each buffered frame's server time minus the time its content shows (seconds)."""
    return [f.t_server_s - (T0 + (f.frame.seq - 1) / 30) for f in hub.sensors["cam"].frames]


def test_the_stored_lag_places_frames_when_their_content_happened() -> None:
    hub = registered(calibration({"cam": 0.04}))
    streamed(hub)
    assert hub.sensors["cam"].clock_source == "round_trip"
    assert np.allclose(placed_lateness(hub)[3:], 0.0, atol=0.002)


def test_without_a_lag_the_frames_are_late_by_it() -> None:
    for stored in (None, calibration({"cam": None}), calibration({"other": 0.04})):
        hub = registered(stored)
        streamed(hub)
        assert np.allclose(placed_lateness(hub)[3:], 0.04, atol=0.002)


def test_a_new_calibration_moves_the_buffered_frames_and_the_next_ones() -> None:
    hub = registered(None)
    streamed(hub, 0.5)
    hub.use_calibration(calibration({"cam": 0.04}, version=2))
    assert np.allclose(placed_lateness(hub)[3:], 0.0, atol=0.002)
    streamed(hub, 0.5, start=0.5)
    times = [f.t_server_s for f in hub.sensors["cam"].frames]
    assert times == sorted(times)
    assert np.allclose(placed_lateness(hub)[3:], 0.0, atol=0.002)
    hub.use_calibration(calibration({"cam": 0.01}, version=3))
    assert np.allclose(placed_lateness(hub)[3:], 0.03, atol=0.002)


def test_the_lag_counts_in_the_stale_check() -> None:
    hub = registered(calibration({"cam": 0.3}))
    streamed(hub, 0.5)
    # Received 0.25 s after its stamp: 0.55 s after what it shows with the lag, past STALE_S.
    stamp = round((T0 + 0.75 - OFFSET) * 1e9)
    hub.handle_message(b"a", [encode(Frame(1000, stamp, ()))], T0 + 1.0, 1.0)
    assert hub.sensors["cam"].frames_rejected["stale"] == 1


@pytest.mark.parametrize(
    ("stored", "expected"),
    [(None, 0.0), ({"cam": None}, 0.0), ({"x": 0.5}, 0.0), ({"cam": -0.02}, -0.02)],
)
def test_calibrated_lag(stored: dict[str, float | None] | None, expected: float) -> None:
    assert calibrated_lag_s(None if stored is None else calibration(stored), "cam") == expected
