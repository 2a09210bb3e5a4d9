"""Pacing of slow WebSocket clients (server/feed_pacing.py), with the time passed in."""

from __future__ import annotations

from skelfuse.server.feed_pacing import Pacer

FRAME_S = 1 / 30


def test_a_client_that_answers_promptly_gets_a_ping_every_few_frames_and_is_never_held() -> None:
    pacer = Pacer(ping_every=10)
    pings = 0
    for step in range(100):
        now = step * FRAME_S
        ping, wait = pacer.after_frame(now)
        assert not wait
        if ping:
            pings += 1
            pacer.on_pong(now + 0.002)
    assert pings == 1 + 99 // 10 and not pacer.paced


def test_a_late_pong_paces_the_client_within_a_few_frames() -> None:
    pacer = Pacer(late_pong_s=0.1)
    assert pacer.after_frame(0.0) == (True, False)  # the first message is followed by a ping
    held = [pacer.after_frame(step * FRAME_S)[1] for step in range(1, 6)]
    assert held == [False, False, False, True, True]  # 0.133 s > 0.1 s: wait for that pong
    assert pacer.paced


def test_a_paced_client_gets_a_ping_after_every_frame_until_it_answers_quickly() -> None:
    pacer = Pacer(quick_pong_s=0.02)
    pacer.on_full()  # its socket refused bytes
    for read_at in (0.2, 0.4, 0.6):  # one frame per read, 5 reads a second
        assert pacer.after_frame(read_at - 0.2) == (True, True)
        pacer.on_pong(read_at)
        assert pacer.paced
    assert pacer.after_frame(0.6) == (True, True)
    pacer.on_pong(0.605)  # it keeps up again
    assert not pacer.paced and pacer.after_frame(0.64) == (False, False)
