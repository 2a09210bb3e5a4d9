"""Calibration through REST with real agents over ZeroMQ and a real uvicorn server."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import httpx
import numpy as np
import pytest

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.scenarios import Segment
from skelfuse.calibration.rigid import pose_error
from skelfuse.protocol.transform import apply, invert, look_at_pose
from tests.integration.conftest import AgentThread, LiveServer
from tests.support import wait_until

pytestmark = pytest.mark.timeout(150)

POSITIONS = {"cam-a": (0.0, 1.0, 3.0), "cam-b": (2.6, 1.4, -1.5), "cam-c": (-2.6, 0.8, -1.5)}
WALKER = Segment(ProceduralPerformer(1), 0.0, 6.3)
"""The routine's walk around the room, looped: what a user does for a calibration. The whole
routine, whose phase follows the wall clock, sometimes left a 15 s capture with only a few
seconds of walking (turning, arm raises, squats on the spot): a poorly conditioned skeleton fit
that CI caught as a 3° / 212 mm pose (the fit's trust level says so; bench/calibration/methods.py
measures that)."""


def true_pose(sensor_id: str) -> np.ndarray:
    return look_at_pose(POSITIONS[sensor_id], (0.0, 1.0, 0.0))


def start_agents(
    live: LiveServer,
    agent_factory: Callable[..., AgentThread],
    ids: list[str],
    without_depth: tuple[str, ...] = (),
) -> None:
    for sensor_id in ids:
        agent_factory(
            live.zmq_url,
            sensor_id,
            POSITIONS[sensor_id],
            pose_hint=False,
            depth=sensor_id not in without_depth,
            performer=WALKER,
        )

    def connected() -> bool:
        rows = httpx.get(live.http_url + "/api/sensors").json()["sensors"]
        return sorted(r["id"] for r in rows if r["connected"]) == sorted(ids)

    assert wait_until(connected, timeout_s=15)


def world_point_pairs(sensor_id: str, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Four room points the user would measure, seen from the sensor (3 mm picking noise)."""
    world = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [-0.5, 1.8, 0.3], [0.4, 0.9, -1.0]])
    in_sensor = apply(invert(true_pose(sensor_id)), world) + rng.normal(0, 0.003, world.shape)
    return [
        {"sensor": s.tolist(), "reference": w.tolist()}
        for s, w in zip(in_sensor, world, strict=True)
    ]


def run_until_finished(live: LiveServer, body: dict[str, Any], timeout_s: float) -> dict[str, Any]:
    response = httpx.post(live.http_url + "/api/calibration/runs", json=body)
    assert response.status_code == 202, response.text
    run = response.json()
    deadline = time.monotonic() + timeout_s
    while run["state"] in ("capturing", "solving") and time.monotonic() < deadline:
        time.sleep(0.5)
        run = httpx.get(f"{live.http_url}/api/calibration/runs/{run['id']}").json()
    return dict(run)


def test_points_calibration_commit_history_rollback_export_import(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    start_agents(live_server, agent_factory, ["cam-a", "cam-b"])
    url = live_server.http_url
    sensors = httpx.get(url + "/api/sensors").json()["sensors"]
    assert {s["calibration"]["state"] for s in sensors} == {"uncalibrated"}
    assert httpx.get(url + "/api/persons").json()["persons"] == [], "nothing fused uncalibrated"

    rng = np.random.default_rng(4)
    body = {
        "method": "points",
        "reference": "world",
        "points": [{"sensor": s, "pairs": world_point_pairs(s, rng)} for s in ("cam-a", "cam-b")],
    }
    run = run_until_finished(live_server, body, 5)
    assert run["state"] == "done", run
    for sensor_id, result in run["results"].items():
        rotation_deg, translation_mm = pose_error(
            np.asarray(result["T_world_from_sensor"]), true_pose(sensor_id)
        )
        assert rotation_deg < 1.0 and translation_mm < 20.0, (sensor_id, result)
        assert 0 < result["residual_mm"] < 15
        assert len(result["metrics"]["residuals_mm"]) == 4

    committed = httpx.post(f"{url}/api/calibration/runs/{run['id']}/commit")
    assert committed.status_code == 200, committed.text
    assert committed.json()["version"] == 1
    again = httpx.post(f"{url}/api/calibration/runs/{run['id']}/commit")
    assert again.status_code == 409 and "already committed" in again.json()["detail"]
    states = {
        s["id"]: s["calibration"]["state"]
        for s in httpx.get(url + "/api/sensors").json()["sensors"]
    }
    assert states == {"cam-a": "stored", "cam-b": "stored"}
    assert wait_until(lambda: httpx.get(url + "/api/persons").json()["persons"], 10), (
        "fusion must use the committed calibration from the next frame"
    )

    exported = httpx.get(url + "/api/calibration/export")
    assert exported.status_code == 200
    assert "attachment" in exported.headers["content-disposition"]
    second = run_until_finished(live_server, body, 5)
    httpx.post(f"{url}/api/calibration/runs/{second['id']}/commit").raise_for_status()
    rolled = httpx.post(url + "/api/calibration/rollback", json={"version": 1})
    assert rolled.status_code == 200 and rolled.json()["version"] == 3
    imported = httpx.post(url + "/api/calibration/import", json=exported.json())
    assert imported.status_code == 200 and imported.json()["version"] == 4
    history = httpx.get(url + "/api/calibration/history").json()
    assert [v["version"] for v in history["versions"]] == [1, 2, 3, 4]
    assert history["active"] == 4
    assert "rollback to v1" in history["versions"][2]["note"]
    active = httpx.get(url + "/api/calibration").json()
    np.testing.assert_allclose(
        active["sensors"]["cam-b"]["T_world_from_sensor"],
        exported.json()["sensors"]["cam-b"]["T_world_from_sensor"],
    )


def test_calibration_survives_a_server_restart(
    server_factory: Callable[..., LiveServer], agent_factory: Callable[..., AgentThread]
) -> None:
    first = server_factory()
    start_agents(first, agent_factory, ["cam-a"])
    rng = np.random.default_rng(1)
    body = {"method": "points", "reference": "world",
            "points": [{"sensor": "cam-a", "pairs": world_point_pairs("cam-a", rng)}]}  # fmt: skip
    run = run_until_finished(first, body, 5)
    httpx.post(f"{first.http_url}/api/calibration/runs/{run['id']}/commit").raise_for_status()
    first.stop()
    second = server_factory()
    assert wait_until(
        lambda: httpx.get(second.http_url + "/api/persons").json()["persons"], timeout_s=15
    ), "the stored calibration must be used from the first frames after a restart"
    assert httpx.get(second.http_url + "/api/calibration").json()["version"] == 1


@pytest.mark.parametrize(
    ("body", "status", "message"),
    [
        (
            {
                "method": "points",
                "reference": "world",
                "points": [
                    {
                        "sensor": "cam-a",
                        "pairs": [{"sensor": [0, 0, 1], "reference": [0, 0, 1]}] * 2,
                    }
                ],
            },
            400,
            "3",
        ),
        (
            {
                "method": "points",
                "reference": "world",
                "points": [
                    {
                        "sensor": "cam-a",
                        "pairs": [{"sensor": [i, 0, 1], "reference": [i, 0, 1]} for i in range(4)],
                    }
                ],
            },
            400,
            "collinear",
        ),
        (
            {
                "method": "points",
                "reference": "world",
                "points": [
                    {
                        "sensor": "cam-a",
                        "pairs": [{"sensor": [float("nan"), 0, 1], "reference": [0, 0, 1]}] * 3,
                    }
                ],
            },
            422,
            "",
        ),
        (
            {
                "method": "points",
                "reference": "world",
                "points": [
                    {"sensor": "nope", "pairs": [{"sensor": [0, 0, 1], "reference": [0, 0, 1]}] * 3}
                ],
            },
            409,
            "unknown sensor",
        ),
        ({"method": "points", "reference": "world"}, 409, ""),
        ({"method": "skeleton"}, 409, "at least 2"),
        ({"method": "icp"}, 409, "icp refines existing poses"),
        ({"method": "magic"}, 422, ""),
        ({"method": "skeleton", "duration_s": 1}, 422, ""),
        ({"method": "skeleton", "sensors": ["cam-a", "ghost"]}, 409, "unknown sensor"),
        ({"method": "sensor"}, 400, "method sensor needs 'sensor'"),
        ({"method": "sensor", "sensor": "ghost"}, 409, "unknown sensor"),
        ({"method": "sensor", "sensor": "cam-a"}, 409, "other connected sensor with a pose"),
    ],
)
def test_bad_calibration_requests_get_a_clear_4xx(
    live_server: LiveServer,
    agent_factory: Callable[..., AgentThread],
    body: dict[str, Any],
    status: int,
    message: str,
) -> None:
    start_agents(live_server, agent_factory, ["cam-a"])
    response = httpx.post(live_server.http_url + "/api/calibration/runs", content=_json(body),
                          headers={"content-type": "application/json"})  # fmt: skip
    assert response.status_code == status, response.text
    assert message.lower() in response.text.lower()
    assert httpx.get(live_server.http_url + "/api/calibration").json()["version"] is None


def _json(body: dict[str, Any]) -> str:
    import json

    return json.dumps(body)  # allows NaN on purpose: a client may send it


def test_other_bad_requests(live_server: LiveServer) -> None:
    url = live_server.http_url
    assert httpx.post(url + "/api/calibration/runs/nope/commit").status_code == 404
    assert httpx.get(url + "/api/calibration/runs/nope").status_code == 404
    assert httpx.post(url + "/api/calibration/rollback", json={"version": 7}).status_code == 404
    assert httpx.get(url + "/api/calibration/export").status_code == 404
    bad = httpx.post(
        url + "/api/calibration/import",
        json={
            "format": 1,
            "sensors": {
                "a": {
                    "T_world_from_sensor": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
                }
            },
        },
    )
    assert bad.status_code == 400 and "rigid" in bad.json()["detail"]
    assert httpx.post(url + "/api/calibration/runs", json={"method": "auto"}).status_code == 409


def test_auto_calibration_finds_sensors_and_floor_with_no_equipment(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    ids = ["cam-a", "cam-b", "cam-c"]
    start_agents(live_server, agent_factory, ids)
    run = run_until_finished(live_server, {"method": "auto", "duration_s": 15}, timeout_s=110)
    assert run["state"] == "done", run
    results = run["results"]
    assert set(results) == set(ids)
    reference = np.asarray(results["cam-a"]["T_world_from_sensor"])
    for sensor_id in ("cam-b", "cam-c"):
        estimate = invert(reference) @ np.asarray(results[sensor_id]["T_world_from_sensor"])
        truth = invert(true_pose("cam-a")) @ true_pose(sensor_id)
        rotation_deg, translation_mm = pose_error(estimate, truth)
        # Accuracy targets are bench/calibration/methods.py's job; here: the API path ends near
        # truth (ICP can be only partly constrained when two sensors share little besides the
        # floor).
        assert rotation_deg < 2.0 and translation_mm < 80, (
            sensor_id,
            rotation_deg,
            translation_mm,
            results[sensor_id],
        )
        # ICP ran on every sensor: applied, or refused with its reason (a correction larger
        # than the skeleton estimate can be off, which a loaded machine's poorer skeleton
        # estimate can ask for; the pose above is then the skeleton's, still near the truth).
        result = results[sensor_id]
        assert "icp_applied" in result["metrics"], result
        if "icp" not in result["method"]:
            assert result["metrics"]["icp_applied"] is False, result
            assert any("kept the initial pose" in w for w in result["warnings"]), result
    # Floor: every sensor at its true height, world +Y is the true up. Where ICP refused its
    # correction (above), the height and tilt are the skeleton fit's, levelled: looser. Where it
    # applied it, 30 mm: a loaded machine's capture left one sensor 22 mm high (CI run with
    # benchmarks alongside, 2026-11-22); the calibration benchmark's ICP p95 is 45 mm.
    for sensor_id in ids:
        pose = np.asarray(results[sensor_id]["T_world_from_sensor"])
        refined = results[sensor_id]["metrics"].get("icp_applied", True)
        height_mm, tilt_deg = (30, 0.7) if refined else (50, 2.0)
        assert pose[1, 3] == pytest.approx(POSITIONS[sensor_id][1], abs=height_mm / 1000), (
            sensor_id,
            results[sensor_id],
        )
        up_in_sensor = pose[1, :3]
        true_up = true_pose(sensor_id)[1, :3]
        assert np.degrees(np.arccos(np.clip(up_in_sensor @ true_up, -1, 1))) < tilt_deg
    assert run["floor"]["source"] == "depth"


def test_auto_without_depth_keeps_the_skeleton_poses_and_says_so(
    live_server: LiveServer, agent_factory: Callable[..., AgentThread]
) -> None:
    start_agents(live_server, agent_factory, ["cam-a", "cam-b"], without_depth=("cam-b",))
    run = run_until_finished(live_server, {"method": "auto", "duration_s": 12}, timeout_s=60)
    assert run["state"] == "done", run
    assert any("no ICP refinement" in w and "cam-b" in w for w in run["warnings"]), run
    assert run["results"]["cam-b"]["method"] == "skeleton"
    icp = httpx.post(live_server.http_url + "/api/calibration/runs", json={"method": "icp"})
    assert icp.status_code == 409  # nothing committed yet: icp has no poses to refine


def test_import_keeps_an_rgb_cameras_intrinsics_and_lag(live_server: LiveServer) -> None:
    """A file from ``skelfuse calibration import`` (intrinsics and lag per sensor) goes through
    the REST import and export unchanged; impossible intrinsics are refused with 400."""
    url = live_server.http_url
    intrinsics = {
        "width": 1088,
        "height": 1920,
        "fx": 1681.2,
        "fy": 1681.1,
        "cx": 533.0,
        "cy": 948.1,
        "distortion": [-0.046, 0.14, 0.0006, 0.0007, 0.0],
    }
    sensor = {"T_world_from_sensor": np.eye(4).tolist(), "method": "import:qualisys"}
    body = {"format": 1, "sensors": {"cam03": {**sensor, "intrinsics": intrinsics, "lag_s": 0.039}}}
    imported = httpx.post(url + "/api/calibration/import", json=body)
    assert imported.status_code == 200, imported.text
    active = httpx.get(url + "/api/calibration").json()["sensors"]["cam03"]
    assert active["intrinsics"] == intrinsics and active["lag_s"] == 0.039
    exported = httpx.get(url + "/api/calibration/export").json()["sensors"]["cam03"]
    assert exported["intrinsics"] == intrinsics
    landscape = {**intrinsics, "width": 1920, "height": 900}  # the centre falls outside
    bad = {"format": 1, "sensors": {"cam03": {**sensor, "intrinsics": landscape}}}
    refused = httpx.post(url + "/api/calibration/import", json=bad)
    assert refused.status_code == 400 and "outside" in refused.json()["detail"]
