"""The solver worker's first call does not start the process on the event loop's thread
(server/solver_pool.py): starting a process costs the submitting thread 10-25 ms, more on a
loaded machine, so ``ProcessSolvers.run`` submits from a thread. The start is made slow on
purpose here (0.5 s), so done on the loop it would stop the loop that long."""

from __future__ import annotations

import asyncio
import math
import time
from concurrent.futures import ProcessPoolExecutor

import pytest

from skelfuse.server.solver_pool import ProcessSolvers

SLOW_START_S = 0.5


@pytest.mark.timeout(120)
async def test_the_first_call_starts_the_worker_off_the_loop(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    solvers = ProcessSolvers()
    new_pool = ProcessSolvers._new_pool

    def slow_new_pool(self: ProcessSolvers) -> ProcessPoolExecutor:
        time.sleep(SLOW_START_S)  # like a fork and exec on a busy machine (the GIL is free)
        return new_pool(self)

    monkeypatch.setattr(ProcessSolvers, "_new_pool", slow_new_pool)
    task = asyncio.ensure_future(solvers.run(math.sqrt, 16.0))
    worst = 0.0
    while not task.done():
        before = time.perf_counter()
        await asyncio.sleep(0.005)
        worst = max(worst, time.perf_counter() - before - 0.005)
    try:
        assert task.result() == 4.0
    finally:
        await solvers.aclose()
    # The loop's own stalls on a loaded machine stay well under the slow start.
    assert worst < SLOW_START_S * 0.8, f"the loop stopped {worst:.2f} s"
