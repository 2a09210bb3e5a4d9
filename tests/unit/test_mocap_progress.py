"""skelfuse.cli.mocap_progress: frames done of the total and the time left, on an injected clock."""

from __future__ import annotations

import io

from skelfuse.cli.mocap_progress import Progress, format_eta


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_time_left_is_the_rate_so_far_over_what_remains() -> None:
    clock, out = Clock(), io.StringIO()
    progress = Progress("detecting", out, clock=clock, interactive=False)
    progress.set_total(0, 100)
    progress.set_total(1, 300)
    clock.now += 10.0
    progress.update(0, 100)  # 100 frames in 10 s: 300 more take 30 s
    assert progress.line() == "detecting: 100/400 frames (25 %), about 30 s left"
    clock.now += 50.0
    progress.update(1, 300)
    assert progress.line() == "detecting: 400/400 frames (100 %), 1 min 00 s"


def test_a_log_gets_a_line_at_the_start_and_per_tenth() -> None:
    clock, out = Clock(), io.StringIO()
    progress = Progress("fusing", out, clock=clock, interactive=False)
    progress.set_total(0, 100)
    for done in range(1, 101):
        clock.now += 0.1
        progress.update(0, done)
    progress.finish()
    lines = out.getvalue().splitlines()
    assert len(lines) == 11  # the first frame, 10 %, ... 100 %; finish adds nothing after 100 %
    assert lines[0] == "fusing: 1/100 frames (1 %), about 10 s left"
    assert lines[1] == "fusing: 10/100 frames (10 %), about 9 s left"
    assert lines[-1] == "fusing: 100/100 frames (100 %), 10 s"


def test_a_terminal_gets_one_line_redrawn_in_place() -> None:
    clock, out = Clock(), io.StringIO()
    progress = Progress("detecting", out, clock=clock, interactive=True)
    progress.set_total(0, 4)
    for done in range(1, 5):
        clock.now += 1.0
        progress.update(0, done)
    progress.finish()
    text = out.getvalue()
    assert text.count("\r") == 5 and text.count("\n") == 1 and text.endswith("4 s\n")


def test_more_frames_than_the_header_said_never_exceed_the_total() -> None:
    progress = Progress("detecting", io.StringIO(), clock=Clock(), interactive=False)
    progress.set_total(0, 10)
    progress.update(0, 12)
    assert progress.line().startswith("detecting: 12/12 frames (100 %)")


def test_eta_format() -> None:
    assert [format_eta(s) for s in (0.4, 59.6, 61, 3599, 3725)] == [
        "0 s",
        "1 min 00 s",
        "1 min 01 s",
        "59 min 59 s",
        "1 h 02 min",
    ]
