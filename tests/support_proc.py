"""Processes seen through /proc (Linux; no procps needed): whether one still runs, its children.

For the tests that kill a parent outright and check that nothing it started is left behind.
"""

from __future__ import annotations

import time
from pathlib import Path


def alive(pid: int) -> bool:
    """Running or sleeping; a zombie (exited, not yet reaped by whoever adopted it) is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    state = next(line for line in status.splitlines() if line.startswith("State:"))
    return "Z" not in state.split()[1]


def gone_within(pid: int, timeout_s: float) -> bool:
    """Whether ``pid`` is gone (see :func:`alive`) within ``timeout_s`` seconds (polls 50 Hz)."""
    deadline = time.monotonic() + timeout_s
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.02)
    return not alive(pid)


def children_of(pid: int) -> list[int]:
    """The live processes whose parent is ``pid`` (from /proc/*/stat)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        # "pid (comm) state ppid ...": comm may hold spaces and parentheses.
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and alive(int(entry.name)):
            found.append(int(entry.name))
    return found
