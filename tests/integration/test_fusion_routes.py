"""REST for reference bone lengths (server/routes_fusion.py) on the real app.

The app is driven in-process through ``httpx.ASGITransport`` (no sockets, no lifespan), with a
:class:`FusionHub` put where the lifespan would put it.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable

import httpx
import numpy as np
import pytest

from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.fusion.settings import (
    MirrorSettings,
    SmoothingSettings,
    TrackingSettings,
    WeightSettings,
)
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import BONE_NAMES, JOINT_COUNT, TrackingState
from skelfuse.server.app import create_app
from skelfuse.server.hub import FusionHub
from skelfuse.server.routes_fusion import router
from skelfuse.server.settings import FusionSettings, Settings
from tests.integration.conftest import LiveServer


@pytest.fixture
async def client() -> AsyncIterator[httpx.AsyncClient]:
    settings = Settings(fusion=FusionSettings(tracking=TrackingSettings(min_frames=1)))
    app = create_app(settings)
    if not any(getattr(r, "path", "") == "/api/persons/{person_id}/bones" for r in app.routes):
        app.include_router(router)
    app.state.hub = FusionHub(settings)
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://test") as test_client:
        test_client.app = app  # type: ignore[attr-defined]
        yield test_client


def _add_person(client: httpx.AsyncClient) -> int:
    tracker = client.app.state.hub.pipeline  # type: ignore[attr-defined]
    joints = ProceduralPerformer(1).joints_at(20.0)[0]
    states = np.full(JOINT_COUNT, TrackingState.TRACKED, np.uint8)
    person_id: int = tracker.update([View("s0", 1, joints, states)], 0.0)[0].person_id
    return person_id


async def test_get_put_delete_bones(client: httpx.AsyncClient) -> None:
    person_id = _add_person(client)
    got = (await client.get(f"/api/persons/{person_id}/bones")).json()
    assert got["source"] == "none" and set(got["reference"]) == set(BONE_NAMES)
    lengths = dict.fromkeys(BONE_NAMES, 0.25)
    put = await client.put(f"/api/persons/{person_id}/bones", json={"lengths": lengths})
    assert put.status_code == 200
    assert put.json()["source"] == "set" and put.json()["reference"]["hip_right-knee_right"] == 0.25
    deleted = (await client.delete(f"/api/persons/{person_id}/bones")).json()
    assert deleted["source"] == "none"


async def test_bad_lengths_are_refused_with_the_bone_names(client: httpx.AsyncClient) -> None:
    person_id = _add_person(client)
    lengths = dict.fromkeys(BONE_NAMES, 0.25)
    lengths["hip_right-knee_right"] = 3.0
    del lengths["neck-head"]
    response = await client.put(f"/api/persons/{person_id}/bones", json={"lengths": lengths})
    assert response.status_code == 400
    detail = response.json()["detail"]
    assert "hip_right-knee_right" in detail and "neck-head" in detail


async def test_unknown_person_is_404(client: httpx.AsyncClient) -> None:
    assert (await client.get("/api/persons/999/bones")).status_code == 404
    lengths = dict.fromkeys(BONE_NAMES, 0.25)
    response = await client.put("/api/persons/999/bones", json={"lengths": lengths})
    assert response.status_code == 404


async def test_default_bones_apply_to_new_persons(client: httpx.AsyncClient) -> None:
    lengths = dict.fromkeys(BONE_NAMES, 0.3)
    assert (await client.put("/api/bones/default", json={"lengths": lengths})).status_code == 200
    person_id = _add_person(client)
    got = (await client.get(f"/api/persons/{person_id}/bones")).json()
    assert got["source"] == "set"
    assert (await client.delete("/api/bones/default")).json() == {"default": None}


def test_fusion_settings_in_use_are_shown(server_factory: Callable[..., LiveServer]) -> None:
    """On a real uvicorn server started with a deployment's settings."""
    fusion = FusionSettings(
        smoothing=SmoothingSettings(filter="kalman"),
        mirror=MirrorSettings(walk_check_s=0.0),
        weights=WeightSettings(state_weights=(0, 0.5, 1)),
    )
    live = server_factory(fusion=fusion)
    response = httpx.get(live.http_url + "/api/fusion/settings", timeout=5)
    assert response.status_code == 200
    shown = response.json()["fusion"]
    assert shown["smoothing"]["filter"] == "kalman"
    assert shown["mirror"]["walk_check_s"] == 0.0
    assert shown["weights"]["state_weights"] == [0, 0.5, 1]
    assert shown["learning"]["enabled"] is True and shown["alignment"]["policy"] == "deadline"
    assert set(shown) == set(FusionSettings.__dataclass_fields__)
    assert set(shown["mirror"]) == set(MirrorSettings.__dataclass_fields__)
