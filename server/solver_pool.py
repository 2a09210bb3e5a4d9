"""Where calibration runs do their math: a worker process, so the event loop never waits for it.

ICP (open3d) keeps the GIL for seconds: in a thread of the server it stopped the event loop for
2.3–5.4 s, long enough for agents to think the server gone ("server silent"). The solvers of
:mod:`skelfuse.calibration.solvers` are pure functions of picklable inputs (numpy arrays, small
dataclasses), so :class:`ProcessSolvers` runs them in one ``spawn``-started worker process (not
``fork``: the server has threads and ZeroMQ sockets, which a forked child would inherit broken),
created on first use, kept for the next runs, shut down with the server. Errors the solvers raise
come back as the same exception with the same message; a worker that dies fails the call with
:class:`~skelfuse.server.errors.SolverCrashed`, and the next call gets a fresh worker.

Progress: :meth:`ProcessSolvers.run_reporting` passes the solver a ``progress(fraction,
detail)`` function; in the worker it puts each report on a multiprocessing queue, which a thread
of the server reads and hands to the caller's callback on its event loop
(``loop.call_soon_threadsafe``): the loop never waits for the worker, and a report arriving after
its call ended is dropped.

:class:`ThreadSolvers` runs them in a thread of this process instead: for tests and embedders that
inject solver fakes (which a worker process could not import), not for a live server.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import itertools
import logging
import multiprocessing
import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, ParamSpec, Protocol, TypeVar

from skelfuse.server.errors import SolverCrashed

logger = logging.getLogger(__name__)

P = ParamSpec("P")
T = TypeVar("T")

Progress = Callable[[float, str], None]
"""A solver's progress report: share of its work done (0..1) and what it is doing."""

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

    async def run_reporting(
        self, fn: Callable[..., T], on_progress: Progress, /, *args: Any, **kwargs: Any
    ) -> T:
        """``fn(*args, progress=<reporter>, **kwargs)``'s result; each call of the reporter
        reaches ``on_progress`` on the caller's event loop, until ``fn`` returns.

        Raises:
            SolverCrashed: the worker running it died.
        """
        ...

    async def aclose(self) -> None:
        """Stop the workers (waits for a call still running)."""
        ...


_progress_queue: Any = None
"""In the worker process: where progress reports go (:func:`_init_worker`)."""


PARENT_CHECK_S = 0.5
"""How often the worker checks that the server that started it is still alive."""


def _init_worker(nice: int, progress_queue: Any = None, parent_pid: int | None = None) -> None:
    """Runs first in the worker process."""
    global _progress_queue
    _progress_queue = progress_queue
    if nice and hasattr(os, "nice"):
        os.nice(nice)
    if parent_pid is not None:
        threading.Thread(
            target=_exit_with_parent, args=(parent_pid,), name="solver-parent", daemon=True
        ).start()


def _exit_with_parent(parent_pid: int) -> None:
    """In the worker: end the process once the server is gone. A server killed outright (SIGKILL,
    a crash, a CI timeout) never shuts its pool down, and the worker would otherwise wait on its
    call queue for ever, an orphan holding memory (seen here as workers re-parented to init).
    Polling ``getppid`` rather than ``PR_SET_PDEATHSIG``: the latter fires when the *thread* that
    started the worker ends, and :meth:`ProcessSolvers.warm` starts it from a short-lived thread."""
    while os.getppid() == parent_pid:
        threading.Event().wait(PARENT_CHECK_S)
    os._exit(0)


def _call_reporting(
    fn: Callable[..., T], call_id: int, args: tuple[Any, ...], kwargs: dict[str, Any]
) -> T:
    """In the worker: ``fn`` with a ``progress`` that puts ``(call_id, fraction, detail)`` on the
    progress queue (a put does not wait: the queue's feeder thread sends it)."""
    queue = _progress_queue

    def report(fraction: float, detail: str) -> None:
        if queue is not None:
            queue.put((call_id, float(fraction), str(detail)))

    return fn(*args, progress=report, **kwargs)


class _ProgressReader:
    """A thread of the server reading one worker's progress queue and handing each report to
    the listener of its call, on the listener's event loop."""

    def __init__(
        self,
        queue: Any,
        listeners: dict[int, tuple[asyncio.AbstractEventLoop, Progress]],
    ) -> None:
        self.queue = queue
        self._listeners = listeners
        self._thread = threading.Thread(target=self._read, name="solver-progress", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while True:
            try:
                item = self.queue.get()
            except (EOFError, OSError, ValueError):  # the queue was closed under us
                return
            if item is None:
                return
            call_id, fraction, detail = item
            listener = self._listeners.get(call_id)
            if listener is None:  # its call has returned: a late report
                continue
            loop, callback = listener
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(callback, fraction, detail)

    def stop(self) -> None:
        """Let the thread end (it reads the end mark after any report still queued)."""
        with contextlib.suppress(OSError, ValueError):
            self.queue.put(None)


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
        self._reader: _ProgressReader | None = None
        self._listeners: dict[int, tuple[asyncio.AbstractEventLoop, Progress]] = {}
        self._call_ids = itertools.count(1)
        self._closed = False

    def _new_pool(self) -> ProcessPoolExecutor:
        # A queue per worker: one that died mid-report may leave its queue unreadable.
        if self._reader is not None:
            self._reader.stop()
        queue = self._context.Queue()
        self._reader = _ProgressReader(queue, self._listeners)
        return ProcessPoolExecutor(
            max_workers=1,  # one run at a time, its solves one after another
            mp_context=self._context,
            initializer=_init_worker,
            initargs=(self._nice, queue, os.getpid()),
        )

    def _submit(self, call: Callable[[], T]) -> tuple[ProcessPoolExecutor, Future[T]]:
        with self._lock:
            if self._closed:  # e.g. warm()'s thread starting after the server shut down
                raise SolverCrashed("the solver pool is closed (the server is shutting down)")
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
        threading.Thread(target=self._warm, name="solver-warm").start()

    def _warm(self) -> None:
        with contextlib.suppress(SolverCrashed):  # closed before this thread ran: nothing to do
            self._submit(_preload)

    async def run(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        return await self._run(functools.partial(fn, *args, **kwargs), fn)

    async def run_reporting(
        self, fn: Callable[..., T], on_progress: Progress, /, *args: Any, **kwargs: Any
    ) -> T:
        call_id = next(self._call_ids)
        self._listeners[call_id] = (asyncio.get_running_loop(), on_progress)
        try:
            call = functools.partial(_call_reporting, fn, call_id, args, kwargs)
            return await self._run(call, fn)
        finally:
            self._listeners.pop(call_id, None)

    async def _run(self, call: Callable[[], T], fn: Callable[..., Any]) -> T:
        # Submitting from a thread: the first submit starts the process, 10-25 ms (more under
        # load) of the submitting thread, which must not be the event loop's.
        pool, future = await asyncio.to_thread(self._submit, call)
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
            self._closed = True
            pool, self._pool = self._pool, None
            reader, self._reader = self._reader, None
        if pool is not None:
            await asyncio.to_thread(pool.shutdown, wait=True, cancel_futures=True)
        if reader is not None:
            reader.stop()


class ThreadSolvers:
    """Runs each call in a thread of this process (``asyncio.to_thread``): for tests that inject
    fakes; open3d in a thread stops the event loop while it runs."""

    def warm(self) -> None:
        """Nothing to start: a thread needs no warm-up."""

    async def run(self, fn: Callable[P, T], /, *args: P.args, **kwargs: P.kwargs) -> T:
        return await asyncio.to_thread(fn, *args, **kwargs)

    async def run_reporting(
        self, fn: Callable[..., T], on_progress: Progress, /, *args: Any, **kwargs: Any
    ) -> T:
        loop = asyncio.get_running_loop()
        done = False

        def report(fraction: float, detail: str) -> None:
            if not done:  # as the worker's: nothing after the call returned
                loop.call_soon_threadsafe(on_progress, fraction, detail)

        try:
            return await self.run(fn, *args, progress=report, **kwargs)
        finally:
            done = True

    async def aclose(self) -> None:
        """Nothing to stop: each call's thread ends with it."""
