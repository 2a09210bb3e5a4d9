"""Writes a recording while the server runs, without blocking its event loop.

The server calls :meth:`Recorder.on_hello` / :meth:`Recorder.on_frame` from the ingest task with
the raw bytes of every accepted message. Those calls only pack the record and append it to a
list under a lock (microseconds); a writer thread appends the list to the file and flushes it
every ``flush_interval_s`` (0.5 s), so a crash loses at most the last half second and leaves a
file readable up to its last complete record. :meth:`Recorder.close` writes what is left, the
end record, and fsyncs.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from skelfuse.protocol.recording_file import Header, RecordingError, pack_record

logger = logging.getLogger(__name__)

FLUSH_INTERVAL_S = 0.5


@dataclass(frozen=True, slots=True)
class RecorderStats:
    records: int
    frames: int
    bytes_written: int
    first_t_s: float | None
    last_t_s: float | None
    sensors: tuple[str, ...]
    error: str | None

    @property
    def duration_s(self) -> float:
        if self.first_t_s is None or self.last_t_s is None:
            return 0.0
        return self.last_t_s - self.first_t_s


class Recorder:
    """Records every agent's raw stream into one file (:mod:`skelfuse.protocol.recording_file`).

    Args:
        path: the file to create (it must not exist).
        header: written first, synchronously.
        flush_interval_s: how often the writer thread writes and flushes.
    """

    def __init__(
        self,
        path: str | Path,
        header: Header,
        *,
        flush_interval_s: float = FLUSH_INTERVAL_S,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.path = Path(path)
        self.header = header
        self._clock = clock
        self._flush_interval_s = flush_interval_s
        try:
            self._file: BinaryIO = self.path.open("xb")
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot create ({exc.strerror})") from exc
        head = header.to_msgpack()
        self._file.write(head)
        self._file.flush()
        self._bytes = len(head)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._pending: list[bytes] = []
        self._records = 0
        self._frames = 0
        self._first: float | None = None
        self._last: float | None = None
        self._sensors: set[str] = set()
        self._closed = False
        self._error: str | None = None
        self._thread = threading.Thread(
            target=self._run, name=f"recorder-{self.path.name}", daemon=True
        )
        self._thread.start()

    # --- called from the server's event loop ---------------------------------------------------

    def on_hello(self, sensor_id: str, payload: bytes, t_s: float) -> None:
        self._add(sensor_id, "hello", payload, t_s)

    def on_frame(self, sensor_id: str, payload: bytes, t_s: float) -> None:
        self._add(sensor_id, "frame", payload, t_s)

    def _add(self, sensor_id: str, kind: str, payload: bytes, t_s: float) -> None:
        packed = pack_record(round(t_s * 1e9), sensor_id, kind, payload)
        with self._lock:
            if self._closed or self._error is not None:
                return
            self._pending.append(packed)
            self._records += 1
            self._frames += kind == "frame"
            self._first = t_s if self._first is None else self._first
            self._last = t_s
            self._sensors.add(sensor_id)

    @property
    def closed(self) -> bool:
        return self._closed

    def stats(self) -> RecorderStats:
        with self._lock:
            pending = sum(map(len, self._pending))
            return RecorderStats(
                self._records,
                self._frames,
                self._bytes + pending,
                self._first,
                self._last,
                tuple(sorted(self._sensors)),
                self._error,
            )

    def close(self) -> RecorderStats:
        """Stop: write what is pending and the end record, fsync, close. Idempotent."""
        with self._lock:
            if self._closed:
                return self._stats_unlocked()
            self._closed = True
            self._wake.notify()
        self._thread.join()
        if self._error is None:
            t_end = self._last if self._last is not None else self._clock()
            try:
                end = pack_record(round(t_end * 1e9), "", "end", b"")
                self._file.write(end)
                self._bytes += len(end)
                self._file.flush()
                os.fsync(self._file.fileno())
            except OSError as exc:
                self._error = f"cannot finish {self.path}: {exc}"
                logger.error("%s", self._error)
        self._file.close()
        with self._lock:
            return self._stats_unlocked()

    def _stats_unlocked(self) -> RecorderStats:
        return RecorderStats(
            self._records,
            self._frames,
            self._bytes,
            self._first,
            self._last,
            tuple(sorted(self._sensors)),
            self._error,
        )

    # --- writer thread -------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._lock:
                if not self._closed:
                    self._wake.wait(self._flush_interval_s)
                batch, self._pending = self._pending, []
                closing = self._closed
            if batch:
                try:
                    data = b"".join(batch)
                    self._file.write(data)
                    self._file.flush()
                    self._bytes += len(data)
                except OSError as exc:
                    with self._lock:
                        self._error = f"writing {self.path} failed: {exc}"
                        self._pending = []
                    logger.error("recording stopped: %s", self._error)
                    return
            if closing:
                return
