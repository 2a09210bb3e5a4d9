"""The calibration worker never outlives its server (server/solver_pool.py): a server killed
outright leaves no orphan worker behind, and a ``warm()`` that runs after shutdown starts none.
Both leaked processes on the development machine (workers re-parented to init, for hours)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from skelfuse.server.errors import SolverCrashed
from skelfuse.server.solver_pool import PARENT_CHECK_S, ProcessSolvers
from tests.support_proc import alive

SERVER_STAND_IN = """
import asyncio, os, sys, time
from skelfuse.server.solver_pool import ProcessSolvers

async def main() -> None:
    solvers = ProcessSolvers()
    worker_pid = await solvers.run(os.getpid)
    print(worker_pid, flush=True)
    time.sleep(600)  # killed by the test long before

asyncio.run(main())
"""


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads process states from /proc")
@pytest.mark.timeout(120)
def test_a_killed_server_leaves_no_worker_behind() -> None:
    server = subprocess.Popen(
        [sys.executable, "-c", SERVER_STAND_IN], stdout=subprocess.PIPE, text=True
    )
    try:
        assert server.stdout is not None
        worker_pid = int(server.stdout.readline())
        assert worker_pid != server.pid and alive(worker_pid)
    finally:
        server.send_signal(signal.SIGKILL)  # no shutdown, no atexit: as a crash or a CI kill
        server.wait()
        if server.stdout is not None:
            server.stdout.close()
    deadline = time.monotonic() + 20 * PARENT_CHECK_S + 10.0
    while alive(worker_pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    still_alive = alive(worker_pid)
    if still_alive:
        os.kill(worker_pid, signal.SIGKILL)
    assert not still_alive, "the worker outlived its killed server"


async def test_warm_after_close_starts_no_worker() -> None:
    solvers = ProcessSolvers()
    await solvers.aclose()
    before = {thread.name for thread in threading.enumerate()}
    solvers.warm()
    for thread in threading.enumerate():
        if thread.name == "solver-warm" and thread.name not in before:
            thread.join(timeout=30)
    assert solvers._pool is None
    with pytest.raises(SolverCrashed, match="closed"):
        await solvers.run(os.getpid)
