"""End to end: ``skelfuse demo`` as separate processes, checked against the simulator's truth."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from websockets.asyncio.client import connect

from agent.sim.performer import ProceduralPerformer
from protocol.skeleton import JOINT_COUNT, JointId
from protocol.transform import apply
from tests.conftest import DemoStack

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]


async def collect(stack: DemoStack, seconds: float) -> list[dict[str, object]]:
    frames: list[dict[str, object]] = []
    async with connect(f"{stack.ws_url}/ws/skeletons?token={stack.token}") as ws:
        definition = json.loads(await ws.recv())
        assert definition["type"] == "skeleton"
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            frames.append(json.loads(await ws.recv()))
    return frames


async def test_demo_fuses_close_to_ground_truth(demo_stack: DemoStack) -> None:
    frames = await collect(demo_stack, 8.0)
    assert len(frames) > 8.0 * 25, f"expected ~30 fused frames/s, got {len(frames)} in 8 s"
    truth_model = ProceduralPerformer(demo_stack.persons)
    T_sim_from_world = demo_stack.T_sim_from_world()
    errors, pelvis_errors, people_per_frame = [], [], []
    ids: set[int] = set()
    for frame in frames:
        persons = frame["persons"]
        assert isinstance(persons, list)
        people_per_frame.append(len(persons))
        truth = truth_model.joints_at(float(str(frame["t"])))  # the demo's shared clock
        for person in persons:
            ids.add(person["id"])
            joints = np.array([j if j is not None else [np.nan] * 3 for j in person["joints"]])
            assert joints.shape == (JOINT_COUNT, 3)
            joints = apply(T_sim_from_world, joints)
            # Score against whichever true person this fused person is.
            per_truth = [np.nanmean(np.linalg.norm(joints - t, axis=1)) for t in truth]
            match = int(np.argmin(per_truth))
            errors.append(per_truth[match])
            pelvis_errors.append(np.linalg.norm(joints[JointId.SPINE_BASE] - truth[match][0]))
    assert np.median(people_per_frame) == demo_stack.persons, "both people fused, no duplicate"
    # Through self-calibration, the real processes and the full fusion method, measured here at
    # about 50 mm median MPJPE and 16 mm at the pelvis; the bounds leave room for noise.
    assert np.median(errors) < 0.10, f"median MPJPE {np.median(errors):.3f} m"
    assert np.median(pelvis_errors) < 0.06, f"median pelvis error {np.median(pelvis_errors):.3f} m"
    assert len(ids) <= demo_stack.persons + 2, f"ids should stay stable, saw {sorted(ids)}"


def test_demo_reports_sensors_and_health(demo_stack: DemoStack) -> None:
    sensors = demo_stack.get_json("/api/sensors")["sensors"]
    assert isinstance(sensors, list)
    assert sorted(s["id"] for s in sensors) == ["sim-1", "sim-2", "sim-3"]
    for sensor in sensors:
        assert sensor["connected"]
        assert 25 < sensor["fps"] < 35
        assert sensor["calibration"]["state"] == "stored", "the demo calibrates itself"
        # Nothing malformed ever. A frame can arrive over 0.5 s late ("stale") when a loaded
        # machine deschedules an agent (CI saw 2 of ~1,500 while the demo calibrated itself):
        # counted and dropped as designed, so only a rare one is accepted here.
        rejected = sensor["frames_rejected"]
        assert set(rejected) <= {"stale", "future"}, rejected
        assert sum(rejected.values()) <= 0.01 * sensor["frames_received"], sensor
        # An agent drops a frame rather than queue it when the server cannot take it (no
        # backlog, by design): rare, even on a loaded machine.
        assert sensor["sequence_gaps"] <= 0.01 * sensor["frames_received"], sensor
    calibration = demo_stack.get_json("/api/calibration")
    assert calibration["version"] == 1
    assert "auto" in calibration["note"]
    # The calibrated floor is the simulator's floor: y = 0 maps to y = 0.
    T = demo_stack.T_sim_from_world()
    assert abs(T[1, 3]) < 0.03
    assert np.degrees(np.arccos(np.clip(T[1, 1], -1, 1))) < 1.0
    health = demo_stack.get_json("/api/health")
    assert health["status"] == "ok"
    assert health["sensors_online"] == 3
