"""Pacing of slow WebSocket clients (server/feed_pacing.py), with the time passed in."""

from __future__ import annotations

from skelfuse.server.feed_pacing import Pacer

FRAME_S = 1 / 30


def test_a_client_that_answers_promptly_is_released_and_then_pinged_every_few_frames() -> None:
    pacer = Pacer(ping_every=10, quick_pongs_to_release=2)
    assert pacer.paced  # a new client: each of its first frames waits for its pong
    decisions = []
    for step in range(102):
        now = step * FRAME_S
        ping, wait = pacer.after_frame(now)
        decisions.append((ping, wait))
        if ping:
            pacer.on_pong(now + 0.002)
    assert decisions[:2] == [(True, True), (True, True)] and not pacer.paced
    assert not any(wait for _, wait in decisions[2:])
    assert [ping for ping, _ in decisions[2:]] == ([False] * 9 + [True]) * 10


def test_a_reader_slow_from_the_start_stays_paced_after_one_quick_read() -> None:
    pacer = Pacer(quick_pong_s=0.05, quick_pongs_to_release=2)
    assert pacer.after_frame(0.0) == (True, True)  # the greeting
    pacer.on_pong(0.001)  # read at once with the next read
    for read_at in (0.2, 0.4, 0.6):  # then one message per 0.2 s
        assert pacer.after_frame(read_at - 0.2) == (True, True)
        pacer.on_pong(read_at)
    assert pacer.paced


def test_a_late_pong_paces_a_released_client_within_a_few_frames() -> None:
    pacer = Pacer(late_after_frames=3, ping_every=1, paced=False)
    assert pacer.after_frame(0.0) == (True, False)
    held = [pacer.after_frame(step * FRAME_S)[1] for step in range(1, 6)]
    assert held == [False, False, False, True, True]  # 4 frames after its ping: wait for it
    assert pacer.paced


def test_a_stall_of_the_server_itself_does_not_pace_anyone() -> None:
    pacer = Pacer(late_after_frames=8, ping_every=10, paced=False)
    for step in range(10):
        pacer.after_frame(step * FRAME_S)  # the 10th is followed by a ping
    assert pacer.ping_sent_at is not None
    # the server's loop stalls for 2 s: the pong waits, unread, and no frame is sent meanwhile
    assert pacer.after_frame(2.3) == (False, False)
    pacer.on_pong(2.31)
    assert not pacer.paced


def test_a_paced_client_gets_a_ping_after_every_frame_until_it_answers_quickly() -> None:
    pacer = Pacer(quick_pong_s=0.02, quick_pongs_to_release=1, paced=False)
    pacer.on_full()  # its socket refused bytes
    for read_at in (0.2, 0.4, 0.6):  # one frame per read, 5 reads a second
        assert pacer.after_frame(read_at - 0.2) == (True, True)
        pacer.on_pong(read_at)
        assert pacer.paced
    assert pacer.after_frame(0.6) == (True, True)
    pacer.on_pong(0.605)  # it keeps up again
    assert not pacer.paced and pacer.after_frame(0.64) == (False, False)
