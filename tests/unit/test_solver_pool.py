"""The calibration worker process (server/solver_pool.py): same results and errors as a call in
this process, one worker reused, a dead worker reported by name and replaced."""

from __future__ import annotations

import asyncio
import os
from collections.abc import AsyncIterator

import numpy as np
import pytest

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sources.sim import SimSource
from skelfuse.calibration.errors import IcpUnavailable, InvalidInput
from skelfuse.calibration.rigid import fit_rigid
from skelfuse.calibration.solvers import SensorResult, refine_with_depth
from skelfuse.protocol.depth_cloud import decode_reply
from skelfuse.protocol.transform import look_at_pose
from skelfuse.server.errors import SolverCrashed
from skelfuse.server.solver_pool import ProcessSolvers

pytestmark = pytest.mark.timeout(90)


def die() -> None:
    """What a native crash or the OOM killer looks like from outside: the process just ends."""
    os._exit(3)


def no_open3d() -> None:
    raise IcpUnavailable("ICP needs open3d, which does not import (libusb-1.0.so.0): install it")


@pytest.fixture
async def solvers() -> AsyncIterator[ProcessSolvers]:
    pool = ProcessSolvers()
    yield pool
    await pool.aclose()


async def test_icp_in_the_worker_gives_exactly_the_in_process_result(
    solvers: ProcessSolvers,
) -> None:
    poses = {
        "cam-a": look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0)),
        "cam-b": look_at_pose((2.6, 1.4, -1.5), (0.0, 1.0, 0.0)),
    }
    clouds = {
        s: decode_reply(
            SimSource(ProceduralPerformer(1), pose, seed=i, wall_clock_ns=lambda: 0).depth_cloud(
                {"max_points": 5000}
            )
        )
        for i, (s, pose) in enumerate(poses.items())
    }
    start = {"cam-a": SensorResult(poses["cam-a"], "points", 0.0)}
    off = poses["cam-b"].copy()
    off[1, 3] += 0.04
    start["cam-b"] = SensorResult(off, "points", None)
    try:
        here = refine_with_depth("cam-a", clouds, start, 0.3)
    except IcpUnavailable as exc:
        pytest.skip(f"open3d cannot load here: {exc}")
    there = await solvers.run(refine_with_depth, "cam-a", clouds, start, 0.3)
    # open3d's parallel sums differ in the last bits from call to call, in one process too.
    assert there.floor == pytest.approx(here.floor, abs=0.11) and there.warnings == here.warnings
    for sensor_id, result in here.results.items():
        other = there.results[sensor_id]
        np.testing.assert_allclose(other.T_world_from_sensor, result.T_world_from_sensor, atol=1e-9)
        assert other.method == result.method
        assert other.metrics == pytest.approx(result.metrics, abs=0.11)


async def test_one_worker_process_is_started_once_and_reused(solvers: ProcessSolvers) -> None:
    solvers.warm()
    first = await solvers.run(os.getpid)
    assert first != os.getpid()
    assert await solvers.run(os.getpid) == first


async def test_solver_errors_come_back_with_their_class_and_message(
    solvers: ProcessSolvers,
) -> None:
    with pytest.raises(InvalidInput) as here:
        fit_rigid(np.zeros((4, 3)), np.zeros((4, 2)))
    with pytest.raises(InvalidInput) as there:
        await solvers.run(fit_rigid, np.zeros((4, 3)), np.zeros((4, 2)))
    assert str(there.value) == str(here.value)
    with pytest.raises(IcpUnavailable, match=r"libusb-1\.0\.so\.0"):
        await solvers.run(no_open3d)


async def test_a_dead_worker_fails_the_call_and_the_next_call_gets_a_new_one(
    solvers: ProcessSolvers,
) -> None:
    before = await solvers.run(os.getpid)
    with pytest.raises(SolverCrashed, match="worker process died while running die"):
        await solvers.run(die)
    after = await solvers.run(os.getpid)
    assert after not in (before, os.getpid())


async def test_closing_stops_the_worker(solvers: ProcessSolvers) -> None:
    pid = await solvers.run(os.getpid)
    await solvers.aclose()
    gone = False
    for _ in range(100):  # reaped by shutdown(wait=True); allow for a slow kernel
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            gone = True
            break
        await asyncio.sleep(0.05)
    assert gone
