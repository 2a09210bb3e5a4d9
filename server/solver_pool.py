"""Where calibration runs do their math: a worker process, so the event loop never waits for it.

ICP (open3d) keeps the GIL for seconds: in a thread of the server it stopped the event loop for
2.3–5.4 s, long enough for agents to think the server gone ("server silent"). The solvers of
:mod:`skelfuse.calibration.solvers` are pure functions of picklable inputs (numpy arrays, small
dataclasses), so :class:`ProcessSolvers` runs them in one ``spawn``-started worker process (not
``fork``: the server has threads and ZeroMQ sockets, which a forked child would inherit broken),
created on first use, kept for the next runs, shut down with the server. Errors the solvers raise
come back as the same exception with the same message; a worker that dies fails the call with
:class:`~skelfuse.server.errors.SolverCrashed`, and the next call gets a fresh worker.

:class:`ThreadSolvers` runs them in a thread of this process instead: for tests and embedders that
inject solver fakes (which a worker process could not import), not for a live server.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import multiprocessing
import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import ParamSpec, Protocol, TypeVar

from skelfuse.server.errors import SolverCrashed

logger = logging.getLogger(__name__)

P = ParamSpec("P")
T = TypeVar("T")

WORKER_NICE = 10
"""Niceness added to the worker: on a small machine the live feed, not the solve, gets the
cores first (a calibration takes a moment longer under load; fusion keeps its pace)."""


class Solvers(Protocol):
    """Runs a solver call somewhere that does not hold up the event loop."""

    def warm(self) -> None:
        """Start whatever the first call needs now (a process, imports), without waiting."""
        ...

    async def run(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """``fn(*args, **kwargs)``'s result, or its exception.

        Raises:
            SolverCrashed: the worker running it died.
        """
        ...

    async def aclose(self) -> None:
        """Stop the workers (waits for a call still running)."""
        ...


def _init_worker(nice: int) -> None:
    """Runs first in the worker process."""
    if nice and hasattr(os, "nice"):
        os.nice(nice)


def _preload() -> None:
    """Import the solvers and open3d ahead of the first solve (about 2 s), ignoring failures:
    a missing open3d is reported by the solve that needs it, as without a worker."""
    import skelfuse.calibration.solvers  # noqa: F401
    from skelfuse.calibration.errors import IcpUnavailable
    from skelfuse.calibration.open3d_loader import load_open3d

    with contextlib.suppress(IcpUnavailable):
        load_open3d()


class ProcessSolvers:
    """One worker process (``start_method``, default ``spawn``), started lazily and reused."""

    def __init__(self, start_method: str = "spawn", nice: int = WORKER_NICE) -> None:
        self._context = multiprocessing.get_context(start_method)
        self._nice = nice
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()  # warm() submits from a thread of its own

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=1,  # one run at a time, its solves one after another
            mp_context=self._context,
            initializer=_init_worker,
            initargs=(self._nice,),
        )

    def _submit(self, call: Callable[[], T]) -> tuple[ProcessPoolExecutor, Future[T]]:
        with self._lock:
            if self._pool is None:
                self._pool = self._new_pool()
            try:
                return self._pool, self._pool.submit(call)
            except BrokenProcessPool:  # it died between calls (e.g. while warming): a fresh one
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = self._new_pool()
                return self._pool, self._pool.submit(call)

    def warm(self) -> None:
        # Starting the process costs the calling thread 10–25 ms (fork and exec of a big
        # process): not the event loop's. Nobody waits for it; the first solve queues behind it.
        threading.Thread(target=self._submit, args=(_preload,), name="solver-warm").start()

    async def run(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        # Submitting from a thread: the first submit starts the process, 10-25 ms (more under
        # load) of the submitting thread, which must not be the event loop's.
        pool, future = await asyncio.to_thread(self._submit, functools.partial(fn, *args, **kwargs))
        try:
            return await asyncio.wrap_future(future)  # what loop.run_in_executor does
        except BrokenProcessPool as exc:
            with self._lock:
                if self._pool is pool:  # the next call starts a fresh worker
                    self._pool = None
            pool.shutdown(wait=False, cancel_futures=True)
            name = getattr(fn, "__name__", repr(fn))
            logger.error("the calibration worker died running %s: %s", name, exc)
            raise SolverCrashed(
                f"the calibration worker process died while running {name} ({exc}); the "
                "next run starts a new one: run the calibration again"
            ) from exc

    async def aclose(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            await asyncio.to_thread(pool.shutdown, wait=True, cancel_futures=True)


class ThreadSolvers:
    """Runs each call in a thread of this process (``asyncio.to_thread``): for tests that inject
    fakes; open3d in a thread stops the event loop while it runs."""

    def warm(self) -> None:
        """Nothing to start: a thread needs no warm-up."""

    async def run(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        return await asyncio.to_thread(fn, *args, **kwargs)

    async def aclose(self) -> None:
        """Nothing to stop: each call's thread ends with it."""
