"""The hub's sessions around faults, with injected clocks: a backlog after a network pause is
counted stale (issue 12 #1), the same connection registering again keeps its clock estimates,
and a second connection for a live sensor is refused unless the holder's connection is gone
(issue 12 #3)."""

from __future__ import annotations

from skelfuse.protocol.wire import ErrorMessage, Frame, Heartbeat, Hello, Welcome, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings

T0 = 1_800_000_000.0  # server wall clock at the start (Unix seconds)
OFFSET = 2.5  # the agent's clock runs 2.5 s behind the server's


def hello() -> bytes:
    return encode(Hello("cam", "sim", "t", 30.0, 0))


def frame(seq: int, captured_server_s: float) -> bytes:
    return encode(Frame(seq, round((captured_server_s - OFFSET) * 1e9), ()))


def streaming_hub() -> FusionHub:
    """``cam`` registered on connection b"a", 3 s of frames at 30 fps and heartbeat echoes."""
    hub = FusionHub(Settings(heartbeat_interval_s=1.0))
    assert isinstance(hub.handle_message(b"a", [hello()], T0, 0.0)[0], Welcome)
    for i in range(90):
        t = i / 30
        hub.handle_message(b"a", [frame(i + 1, T0 + t - 0.01)], T0 + t, t)
        if i % 15 == 0:  # an echo of a server heartbeat sent 2 ms earlier
            echo = Heartbeat(round((T0 + t - OFFSET - 0.001) * 1e9), round((T0 + t - 0.002) * 1e9))
            hub.handle_message(b"a", [encode(echo)], T0 + t, t)
    assert hub.sensors["cam"].clock_source == "round_trip"
    return hub


def test_a_backlog_after_a_pause_is_counted_stale_and_the_clock_kept() -> None:
    hub = streaming_hub()
    offset = hub.sensors["cam"].clock_offset_s
    assert offset is not None and abs(offset - OFFSET) < 0.005
    # The network stalls for 5 s: the sensor goes offline; its frames wait in the network.
    hub.check_liveness(3.0 + 2.9)
    assert not hub.sensors["cam"].connected
    healed, healed_mono = T0 + 8.0, 8.0
    backlog = [(91 + i, T0 + 3.0 + i / 30) for i in range(75)]  # captured 3.0 to 5.5 s
    replies = [hub.handle_message(b"a", [frame(s, t)], healed, healed_mono) for s, t in backlog]
    assert all(r == [] for r in replies), "a stale backlog draws no not_registered errors"
    assert hub.sensors["cam"].frames_rejected["stale"] == 75
    assert "not_registered" not in hub.rejected_unregistered
    # The agent says hello again on the same connection: the clock estimate survives, so its
    # next frame is placed right even if it was delayed (0.3 s here).
    assert isinstance(hub.handle_message(b"a", [hello()], healed, healed_mono)[0], Welcome)
    hub.handle_message(b"a", [frame(200, healed - 0.3)], healed, healed_mono)
    placed = hub.sensors["cam"].frames[-1].t_server_s
    assert abs(placed - (healed - 0.3)) < 0.005
    assert hub.sensors["cam"].clock_source == "round_trip"


def test_a_fresh_frame_from_an_offline_connection_is_asked_to_say_hello() -> None:
    hub = streaming_hub()
    hub.check_liveness(6.0)
    reply = hub.handle_message(b"a", [frame(500, T0 + 6.0)], T0 + 6.0, 6.0)
    assert isinstance(reply[0], ErrorMessage) and reply[0].code == "not_registered"


def test_a_second_connection_is_refused_while_the_holder_is_open() -> None:
    hub = streaming_hub()
    open_connections = {b"a"}
    hub.attach_probe(lambda routing_id: routing_id in open_connections)
    for user_id in (None, "cam"):  # without CurveZMQ, and with the sensor's own key
        reply = hub.handle_message(b"b", [hello()], T0 + 3.0, 3.0, user_id=user_id)[0]
        assert isinstance(reply, ErrorMessage) and reply.code == "sensor_id_in_use"
    assert hub.rejected_unregistered["sensor_id_in_use"] == 2
    open_connections.clear()  # the holder crashed: its connection closed
    reply = hub.handle_message(b"b", [hello()], T0 + 3.0, 3.0, user_id="cam")[0]
    assert isinstance(reply, Welcome)
    assert hub.sensors["cam"].routing_id == b"b"
