"""Mutual capture with every wearer's headset in its own tracking space (``--spaces per-wearer``).

Two headsets without a shared anchor each track in their own space, with its own
``T_world_from_space``: here wearer ``k``'s space is turned ``30 + 45·k`` degrees about +Y and
shifted 1 m (:func:`space_transforms`), and each frame's pose is given in its wearer's space.
Those transforms reach the production hub in one of two ways:

- ``stored``: the truth, as a calibration's ``spaces``;
- ``solved``: by a skeleton calibration run (:class:`~skelfuse.server.calibration_runs.
  CalibrationService`, the server's body-based path) over the wearers' own frames, reference
  ``head-0``, committed to a calibration store in a temporary folder. The run's world is its
  reference's space levelled on its floor with its origin under the people, so the fused
  persons are moved by that gauge (``truth(space 0) · solved(space 0)⁻¹``) before they are
  scored, and the solved transforms' errors are the gauge-fixed ones against the truth.

The calibration walk is a separate simulation (:class:`CalibrationScene`): the wearers stand on
a :data:`CALIBRATION_RING_M` ring, turning their heads as in the case, while one more person
walks the built-in routine's loop (0.9 m round the middle) in front of them all, as the
calibration procedure asks (docs/calibration.md). The case's own scene will not do: its
wearers walk straight lines along their radius, symmetric on the ring, which the body solver
rejects or pairs with the wrong person. Captured synchronously at 30 fps for
:data:`CALIBRATION_S` while a fake clock drives the run, so it takes no wall time.
"""

from __future__ import annotations

import asyncio
import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bench.moving.fused import FPS, FusedCase
from skelfuse.agent.sim.head_mounted import PoseErrors
from skelfuse.agent.sim.mutual import MutualCapture
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.scenarios import RingWalkers
from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.store import Calibration, CalibrationStore, SpaceCalibration
from skelfuse.fusion.settings import HubSettings
from skelfuse.protocol.sensor_pose import pose_from_matrix, pose_matrix
from skelfuse.protocol.transform import Matrix4, invert, pose_from_position_yaw_pitch
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.calibration_run import RunSpec, RunState
from skelfuse.server.calibration_runs import CalibrationService
from skelfuse.server.errors import AgentRequestFailed
from skelfuse.server.hub import FusionHub
from skelfuse.server.solver_pool import ThreadSolvers

CALIBRATION_S = 12.0
CALIBRATION_RING_M = 2.5
T0 = 1_800_000_000.0


def space_transforms(count: int) -> tuple[Matrix4, ...]:
    """Wearer ``k``'s ``T_world_from_space``: yaw ``30 + 45·k``°, 1 m from the world origin."""
    return tuple(
        pose_from_position_yaw_pitch(
            (math.cos(2 * math.pi * k / count), 0.0, math.sin(2 * math.pi * k / count)),
            30.0 + 45.0 * k,
        )
        for k in range(count)
    )


def space_id(wearer: int) -> str:
    return f"quest-{wearer}"


class CalibrationScene:
    """The wearers standing on a ring (persons ``0..n-1``) and a walker looping the built-in
    routine round the middle (person ``n``): world joints, metres."""

    def __init__(self, wearers: int) -> None:
        self._ring = RingWalkers(wearers, CALIBRATION_RING_M)
        self._walker = ProceduralPerformer(1)

    @property
    def person_count(self) -> int:
        return self._ring.person_count + 1

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        return np.concatenate([self._ring.joints_at(t_s), self._walker.joints_at(t_s)])


def calibration_capture(case: FusedCase) -> MutualCapture:
    """The calibration walk of ``case``'s wearers (their rigs and pose errors, seed + 100)."""
    rigs = case.capture().rigs
    errors = PoseErrors(case.position_noise_mm, case.rotation_noise_deg, case.mismatch_ms)
    return MutualCapture(CalibrationScene(len(rigs)), rigs, errors=errors, seed=case.seed + 100)


@dataclass(frozen=True, slots=True)
class Spaces:
    """How a bench hub knows the wearers' spaces: ``calibration`` (its ``spaces``), the truth
    that the frames' poses are given in (``world_from_space``, one per wearer), and the
    ``gauge`` that moves the hub's world onto the truth's. ``errors``: per solved space, the
    gauge-fixed (deg, mm) error against the truth."""

    calibration: Calibration
    world_from_space: tuple[Matrix4, ...]
    gauge: Matrix4
    errors: dict[str, tuple[float, float]]


def stored_spaces(count: int) -> Spaces:
    """The truth stored as the calibration's spaces."""
    truth = space_transforms(count)
    spaces = {space_id(k): SpaceCalibration(w, "manual") for k, w in enumerate(truth)}
    return Spaces(Calibration(1, 0.0, {}, spaces=spaces), truth, np.eye(4), {})


class _FakeClock:
    """Time that moves only when the run sleeps; each sleep streams the frames of that time."""

    def __init__(self, stream: Callable[[float], None]) -> None:
        self.wall, self.mono, self._stream = T0, 100.0, stream

    def time(self) -> float:
        return self.wall

    def monotonic(self) -> float:
        return self.mono

    async def sleep(self, seconds: float) -> None:
        self.wall += seconds
        self.mono += seconds
        self._stream(self.wall)
        await asyncio.sleep(0)


class _NoDepth:
    async def request(self, sensor_id: str, method: str, params: Any, timeout_s: float) -> Any:
        raise AgentRequestFailed("the simulated headsets send no depth")


def solved_spaces(case: FusedCase) -> Spaces:
    """The spaces solved by a skeleton calibration run and committed (module docstring).

    Raises:
        RuntimeError: the run failed (its error).
    """
    return asyncio.run(_solve(case))


async def _solve(case: FusedCase) -> Spaces:
    capture = calibration_capture(case)
    truth = space_transforms(capture.wearer_count)
    names = [f"head-{k}" for k in range(capture.wearer_count)]
    hub = FusionHub(HubSettings())
    for k, name in enumerate(names):
        hello = Hello(name, "sim", "bench", FPS, 0, moving=True, pose_space=space_id(k))
        hub.handle_message(name.encode(), [encode(hello)], T0, 0.0)
    sent = [0]

    def stream(now: float) -> None:
        while T0 + sent[0] / FPS <= now:
            t = sent[0] / FPS
            sent[0] += 1
            for k, name in enumerate(names):
                frame = capture.frame(k, t)
                pose = pose_from_matrix(invert(truth[k]) @ pose_matrix(frame.pose))
                bodies = tuple(Body(o.tracking_id, o.joints_m, o.states) for o in frame.bodies)
                wire = Frame(sent[0], round((T0 + t) * 1e9), bodies, frame.floor, pose)
                hub.handle_message(name.encode(), [encode(wire)], T0 + t, t)

    clock = _FakeClock(stream)
    stream(clock.wall)
    with tempfile.TemporaryDirectory() as folder:
        store = CalibrationStore(Path(folder))
        service = CalibrationService(hub, store, _NoDepth(), clock, solvers=ThreadSolvers())
        run = service.start(RunSpec("skeleton", names[0], tuple(names), CALIBRATION_S))
        (task,) = [t for t in asyncio.all_tasks() if t.get_name() == f"calibration-{run.run_id}"]
        await task
        if run.state != RunState.DONE:
            raise RuntimeError(f"calibration run failed: {run.error}")
        committed = await service.commit(run.run_id)
    solved = [committed.spaces[space_id(k)].T_world_from_space for k in range(len(names))]
    gauge = truth[0] @ invert(solved[0])
    errors = {space_id(k): pose_error(gauge @ solved[k], truth[k]) for k in range(1, len(names))}
    return Spaces(committed, truth, gauge, errors)
