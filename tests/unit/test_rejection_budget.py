"""The per-connection rejection budget (server/rejection_budget.py), with an injected clock, and
the hub dropping a flooding connection's messages unread while a good one is untouched."""

from __future__ import annotations

from skelfuse.protocol.wire import Frame, Hello, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.rejection_budget import RejectionBudget
from skelfuse.server.settings import Settings


def test_the_budget_runs_out_per_connection_and_comes_back_with_the_next_window() -> None:
    budget = RejectionBudget(limit=3, window_s=1.0)
    assert [budget.note(b"a", 0.1 * i) for i in range(3)] == [False, False, True]
    assert budget.exhausted(b"a", 0.5)
    assert not budget.exhausted(b"b", 0.5)  # another connection is not affected
    assert not budget.exhausted(b"a", 1.0)  # the window is over
    assert not budget.note(b"a", 1.0)  # a new window starts counting again
    assert not budget.exhausted(b"a", 1.1)


def test_the_oldest_connections_are_forgotten_beyond_the_limit() -> None:
    budget = RejectionBudget(limit=1, window_s=10.0, max_tracked=8)
    for i in range(8):
        budget.note(bytes([i]), 0.0)
    budget.note(b"new", 0.0)
    assert not budget.exhausted(bytes([0]), 0.0)  # forgotten
    assert budget.exhausted(bytes([7]), 0.0) and budget.exhausted(b"new", 0.0)


def test_the_hub_drops_a_flooder_unread_and_leaves_a_good_agent_alone() -> None:
    hub = FusionHub(Settings())
    hub.handle_message(b"good", [encode(Hello("cam", "sim", "t", 30.0, 0))], 100.0, 0.0)
    for i in range(1000):
        hub.handle_message(b"bad", [b"\xc1garbage"], 100.0, i * 1e-4)
        frame = Frame(i + 1, 100_000_000_000 + i, ())
        hub.handle_message(b"good", [encode(frame)], 100.0 + i * 1e-5, i * 1e-4)
    assert hub.rejected_unregistered["malformed"] == 50
    assert hub.rejected_unregistered["rate_limited"] == 950
    cam = hub.sensors["cam"]
    assert cam.frames_received == 1000 and not cam.frames_rejected
