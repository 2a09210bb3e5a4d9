"""A child process that ends when the process that started it is gone.

``skelfuse demo`` starts the server and the simulated agents as processes of their own. A demo
stopped in order stops them, but a demo killed outright (SIGKILL, the OOM killer, a CI timeout)
runs no cleanup, and its children went on for hours re-parented to init (issue 11). The
starter names itself in the child's environment (:data:`PARENT_PID_VARIABLE`); the child's
command line calls :func:`watch_parent_from_environment`, and a daemon thread then watches
that process:

- POSIX: ``os.getppid()`` polled every ``interval_s``; a parent that dies re-parents the child
  (to init or a subreaper), so the value changes. This is what the calibration solver pool does
  (``server/solver_pool.py``). ``PR_SET_PDEATHSIG`` is not used: it fires when the *thread*
  that started the child ends, not the process, which would stop children started from a
  short-lived thread while their parent is alive.
- Windows: a wait on the parent's process handle (``WaitForSingleObject``), no polling.

Once the parent is gone the child is stopped in order first (SIGTERM to itself: uvicorn and the
agent's loop stop on it, the agents say bye), and ended with ``os._exit`` if it is still running
``grace_s`` later.

This module is a process setting, not part of a layer, like :mod:`skelfuse.blas`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable
from typing import Final

logger = logging.getLogger(__name__)

PARENT_PID_VARIABLE: Final = "SKELFUSE_PARENT_PID"
"""Environment variable a starter sets to its own pid to have the child end with it."""

POLL_INTERVAL_S: Final = 0.25
"""How often a POSIX child looks at its parent's pid: it outlives a killed parent by at most
this much before its orderly stop begins."""

GRACE_S: Final = 10.0
"""Time the orderly stop has before the process is ended outright."""

EXIT_CODE: Final = 1
"""``os._exit`` status of a child ended outright because its parent died."""


def child_environment(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for a child that should end with this process: ``env`` (default: this
    process's) with :data:`PARENT_PID_VARIABLE` set to this process's pid."""
    return {**(os.environ if env is None else env), PARENT_PID_VARIABLE: str(os.getpid())}


def watch_parent_from_environment(
    *, interval_s: float = POLL_INTERVAL_S, grace_s: float = GRACE_S
) -> threading.Thread | None:
    """Start :func:`watch_parent` for the pid in :data:`PARENT_PID_VARIABLE`, if set.

    The variable is removed from this process's environment, so that this process's own
    children (which inherit the environment) do not watch the wrong process.

    Returns:
        the watching thread, or None when the variable is unset, not a pid, or this platform
        has no way to watch.
    """
    value = os.environ.pop(PARENT_PID_VARIABLE, None)
    if value is None:
        return None
    try:
        parent_pid = int(value)
    except ValueError:
        logger.warning("%s=%r is not a process id; not watching the parent", PARENT_PID_VARIABLE,
                       value)  # fmt: skip
        return None
    return watch_parent(parent_pid, interval_s=interval_s, grace_s=grace_s)


def watch_parent(
    parent_pid: int,
    *,
    interval_s: float = POLL_INTERVAL_S,
    grace_s: float = GRACE_S,
    on_gone: Callable[[], None] | None = None,
) -> threading.Thread | None:
    """Watch ``parent_pid`` in a daemon thread and stop this process once it is gone.

    A parent already gone when this is called (it died while the child started) counts as
    gone at once.

    Args:
        parent_pid: the pid of the process this one must not outlive (POSIX: its parent).
        interval_s: POSIX polling period, seconds.
        grace_s: seconds between the orderly stop (SIGTERM to this process) and ``os._exit``.
        on_gone: called instead of the stop, for tests that watch from inside a test process.

    Returns:
        the started thread, or None on a platform with no way to watch.
    """
    if sys.platform == "win32":
        wait = _windows_waiter(parent_pid)
    elif hasattr(os, "getppid"):

        def wait() -> None:
            stop = threading.Event()
            while os.getppid() == parent_pid:
                stop.wait(interval_s)

    else:  # pragma: no cover - every platform CPython supports has one of the two
        logger.debug("no way to watch the parent process here")
        return None

    def run() -> None:
        wait()
        if on_gone is not None:
            on_gone()
            return
        _stop_this_process(grace_s)

    thread = threading.Thread(target=run, name="parent-watch", daemon=True)
    thread.start()
    return thread


def _stop_this_process(grace_s: float) -> None:
    """SIGTERM to this process (its own handlers stop it in order), then ``os._exit`` after
    ``grace_s`` if that did not end it."""
    logger.warning("the process that started this one is gone; stopping")
    with contextlib.suppress(OSError):  # signalling oneself does not fail on POSIX
        os.kill(os.getpid(), signal.SIGTERM)
    threading.Event().wait(grace_s)
    logger.error("still running %.0f s after the parent died; exiting", grace_s)
    os._exit(EXIT_CODE)


def _windows_waiter(parent_pid: int) -> Callable[[], None]:  # pragma: no cover - Windows only
    """A function that returns once the process ``parent_pid`` has ended (Windows)."""
    import ctypes

    synchronize = 0x00100000
    infinite = 0xFFFFFFFF
    kernel32 = ctypes.WinDLL("kernel32", use_last_error=True)  # type: ignore[attr-defined,unused-ignore]
    handle = kernel32.OpenProcess(synchronize, False, parent_pid)

    def wait() -> None:
        if handle:  # no handle: the process is gone already
            kernel32.WaitForSingleObject(handle, infinite)
            kernel32.CloseHandle(handle)

    return wait
