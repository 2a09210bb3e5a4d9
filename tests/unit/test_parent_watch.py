"""A child started with :func:`skelfuse.parent_watch.child_environment` ends when its starter
is killed outright (issue 11: the demo's server and agents ran on for hours after a SIGKILL)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from skelfuse.parent_watch import PARENT_PID_VARIABLE, watch_parent_from_environment
from tests.support_proc import alive, gone_within

pytestmark = pytest.mark.skipif(
    not Path("/proc").is_dir() or os.name != "posix", reason="reads process states from /proc"
)

# The child: watches as the command line does, and (``ignore``) refuses SIGTERM, so that only
# the grace period's os._exit can end it.
CHILD = """
import os, signal, sys, time
from skelfuse.parent_watch import PARENT_PID_VARIABLE, watch_parent_from_environment
if sys.argv[1] == "ignore":
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
watch_parent_from_environment(interval_s=0.05, grace_s=float(sys.argv[2]))
assert PARENT_PID_VARIABLE not in os.environ  # its own children must not watch the wrong pid
print(os.getpid(), flush=True)
time.sleep(600)
"""

# The starter: starts the child as the demo does, says its pid, then waits to be killed.
STARTER = """
import subprocess, sys, time
from skelfuse.parent_watch import child_environment
child = subprocess.Popen([sys.executable, "-c", sys.argv[1], sys.argv[2], sys.argv[3]],
                         env=child_environment(), stdout=subprocess.PIPE, text=True)
print(child.stdout.readline().strip(), flush=True)
time.sleep(600)
"""


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("sigterm", "grace_s", "within_s"),
    [("obey", 30.0, 10.0), ("ignore", 1.0, 10.0)],
    ids=["orderly-stop", "ended-after-grace"],
)
def test_a_child_ends_with_its_killed_starter(
    sigterm: str, grace_s: float, within_s: float
) -> None:
    starter = subprocess.Popen(
        [sys.executable, "-c", STARTER, CHILD, sigterm, str(grace_s)],
        stdout=subprocess.PIPE,
        text=True,
    )
    child_pid = 0
    try:
        assert starter.stdout is not None
        child_pid = int(starter.stdout.readline())
        assert alive(child_pid)
        time.sleep(0.3)
        assert alive(child_pid), "the child must not end while its starter lives"
    finally:
        starter.send_signal(signal.SIGKILL)  # no cleanup at all, as the OOM killer or a CI kill
        starter.wait()
        if starter.stdout is not None:
            starter.stdout.close()
    started = time.monotonic()
    ended = gone_within(child_pid, within_s)
    if not ended:
        os.kill(child_pid, signal.SIGKILL)
    assert ended, f"the child outlived its killed starter by {within_s} s"
    if sigterm == "ignore":  # ended by os._exit, not before the grace period
        assert time.monotonic() - started >= grace_s - 0.3


def test_nothing_is_watched_without_the_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PARENT_PID_VARIABLE, raising=False)
    assert watch_parent_from_environment() is None
    monkeypatch.setenv(PARENT_PID_VARIABLE, "not-a-pid")
    assert watch_parent_from_environment() is None
    assert PARENT_PID_VARIABLE not in os.environ
