"""Calibration store work does not stop the event loop (server/calibration_runs.py): a commit,
rollback or import writes and fsyncs files, and the history reads one file per version. On a busy
disk that is tens of ms a write (42 ms median on the 2-core test machine), over the loop's 20 ms
budget; it now runs in a thread while the loop keeps ticking.

The disk is made slow on purpose (``os.fsync`` and each version's read sleep, which like the real
calls release the GIL), so run inline the loop would stop for seconds; the bound leaves room for
the shared machine's own stalls (up to a few hundred ms under heavy load).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skelfuse.calibration import store as store_module
from skelfuse.calibration.store import Calibration, CalibrationStore, SensorCalibration
from skelfuse.server.calibration_runs import CalibrationService
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings
from skelfuse.server.solver_pool import ThreadSolvers

SLOW_IO_S = 0.3
"""Each fsync and each version read on the slow disk: a save fsyncs 4 times (1.2 s inline)."""
MAX_STALL_S = 0.6


class NoAgents:
    async def request(
        self, sensor_id: str, method: str, params: dict[str, Any], timeout_s: float
    ) -> Any:
        raise AssertionError("no agent request expected")


async def longest_stall(work: Awaitable[Any], tick_s: float = 0.005) -> tuple[Any, float]:
    """Run ``work`` while a ticker sleeps ``tick_s`` over and over; its result and the longest
    time a tick woke late (s)."""
    task = asyncio.ensure_future(work)
    worst = 0.0
    while not task.done():
        before = time.perf_counter()
        await asyncio.sleep(tick_s)
        worst = max(worst, time.perf_counter() - before - tick_s)
    return task.result(), worst


@pytest.fixture
def service(tmp_path: Path) -> CalibrationService:
    store = CalibrationStore(tmp_path)
    for k in range(3):
        store.save({"cam-a": SensorCalibration(np.eye(4), "points")}, note=f"v{k + 1}")
    return CalibrationService(FusionHub(Settings()), store, NoAgents(), solvers=ThreadSolvers())


@pytest.fixture
def slow_disk(monkeypatch: pytest.MonkeyPatch) -> None:
    read = CalibrationStore._read

    def slow_read(self: CalibrationStore, path: Path) -> Calibration | None:
        time.sleep(SLOW_IO_S)
        return read(self, path)

    monkeypatch.setattr(store_module.os, "fsync", lambda fd: time.sleep(SLOW_IO_S))
    monkeypatch.setattr(CalibrationStore, "_read", slow_read)


@pytest.mark.timeout(60)
async def test_import_rollback_and_history_keep_the_loop_running(
    service: CalibrationService, slow_disk: None
) -> None:
    imported = Calibration(0, 0.0, {"cam-b": SensorCalibration(np.eye(4), "skeleton")}).to_json()
    calibration, stall = await longest_stall(service.import_json(imported))
    assert calibration.version == 4 and service.hub.calibration is calibration
    assert stall < MAX_STALL_S, f"import stopped the loop for {stall:.2f} s"

    calibration, stall = await longest_stall(service.rollback(2))
    assert calibration.version == 5 and service.hub.calibration is calibration
    assert stall < MAX_STALL_S, f"rollback stopped the loop for {stall:.2f} s"

    versions, stall = await longest_stall(service.history())
    assert [c.version for c in versions] == [1, 2, 3, 4, 5]
    assert stall < MAX_STALL_S, f"reading the history stopped the loop for {stall:.2f} s"
