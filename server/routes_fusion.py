"""REST for fusion parameters a user sets per person: reference bone lengths.

Report A measures each person's bone lengths beforehand (standing in front of one sensor for a
few seconds); without that, the server estimates them online (docs/fusion.md). These routes show
both and let an application set, or clear, a person's lengths:

- ``GET /api/persons/{id}/bones``: ``source`` (``set``, ``estimated`` or ``none``), the
  ``reference`` lengths fusion uses and the current online ``estimate``, by bone name (metres,
  ``null`` where unknown).
- ``PUT /api/persons/{id}/bones``: body ``{"lengths": {"hip_right-knee_right": 0.43, ...}}``
  with all 24 bones, each finite and within 0.02–1.0 m; 400 with the offending names otherwise.
- ``DELETE /api/persons/{id}/bones``: back to the online estimate.
- ``PUT /api/bones/default`` / ``DELETE /api/bones/default``: lengths every *new* person starts
  with (useful with a single known performer).
- ``GET /api/fusion/settings``: the fusion settings in use (defaults, or the deployment's
  ``--fusion-config`` file; read-only: they are chosen when the server starts).

Include with ``app.include_router(router)``; the routes read ``request.app.state.hub.pipeline``.
"""

from __future__ import annotations

import math
from typing import Annotated

import numpy as np
import numpy.typing as npt
from fastapi import APIRouter, Request
from pydantic import BaseModel, ConfigDict, StrictFloat, WithJsonSchema

from skelfuse.fusion.config import fusion_settings_as_dict
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.protocol.skeleton import BONE_NAMES
from skelfuse.server.errors import InvalidRequest, NotFound, error_responses

router = APIRouter(tags=["fusion"])

MIN_BONE_M = 0.02
MAX_BONE_M = 1.0


_LENGTH_SCHEMA = {"type": "number", "minimum": MIN_BONE_M, "maximum": MAX_BONE_M}
_LENGTHS_SCHEMA = {
    "type": "object",
    "description": f"all 24 bones of GET /api/skeleton by name, each {MIN_BONE_M}–{MAX_BONE_M} m",
    "properties": dict.fromkeys(BONE_NAMES, _LENGTH_SCHEMA),
    "required": list(BONE_NAMES),
    "additionalProperties": False,
}
"""What :func:`_validated` accepts, published as the schema (issue 12: the document said any
name → number map, so schema-valid bodies were refused)."""


class BoneLengths(BaseModel):
    """Reference bone lengths by name (metres): all 24 of ``GET /api/skeleton``'s bones."""

    model_config = ConfigDict(extra="forbid")
    # Strict: "0.3" is not a length (the schema says number); the checks that name every bad
    # bone stay in _validated, a 400 the client can act on.
    lengths: Annotated[dict[str, StrictFloat], WithJsonSchema(_LENGTHS_SCHEMA)]


def _pipeline(request: Request) -> FusionPipeline:
    pipeline: FusionPipeline = request.app.state.hub.pipeline
    return pipeline


def _by_name(values: npt.NDArray[np.float64]) -> dict[str, float | None]:
    return {
        name: (round(float(v), 4) if math.isfinite(float(v)) else None)
        for name, v in zip(BONE_NAMES, values, strict=True)
    }


def _validated(body: BoneLengths) -> npt.NDArray[np.float64]:
    """The lengths in :data:`BONE_NAMES` order (24,), metres.

    Raises:
        InvalidRequest: unknown or missing bones, or lengths outside 0.02–1.0 m (all listed).
    """
    unknown = sorted(set(body.lengths) - set(BONE_NAMES))
    missing = [name for name in BONE_NAMES if name not in body.lengths]
    bad = sorted(
        name
        for name, value in body.lengths.items()
        if name in BONE_NAMES and not (math.isfinite(value) and MIN_BONE_M <= value <= MAX_BONE_M)
    )
    problems = []
    if unknown:
        problems.append(f"unknown bones {unknown}")
    if missing:
        problems.append(f"missing bones {missing}")
    if bad:
        problems.append(f"lengths must be finite and within {MIN_BONE_M}–{MAX_BONE_M} m: {bad}")
    if problems:
        raise InvalidRequest(
            "; ".join(problems) + f". Expected all of {list(BONE_NAMES)} in metres."
        )
    return np.array([body.lengths[name] for name in BONE_NAMES], dtype=np.float64)


def _person(request: Request, person_id: int) -> dict[str, object]:
    model = _pipeline(request).bone_model(person_id)
    if model is None:
        raise NotFound(f"no person with id {person_id}")
    return {
        "id": person_id,
        "source": model.source,
        "reference": _by_name(model.reference()),
        "estimate": _by_name(model.estimate),
        "units": "m",
    }


@router.get("/api/persons/{person_id}/bones", responses=error_responses(NotFound))
async def get_bones(request: Request, person_id: int) -> dict[str, object]:
    """A person's reference bone lengths, where they come from, and the online estimate."""
    return _person(request, person_id)


@router.put("/api/persons/{person_id}/bones", responses=error_responses(InvalidRequest, NotFound))
async def put_bones(request: Request, person_id: int, body: BoneLengths) -> dict[str, object]:
    """Set a person's reference bone lengths (all 24, metres)."""
    lengths = _validated(body)
    if not _pipeline(request).set_bone_lengths(person_id, lengths):
        raise NotFound(f"no person with id {person_id}")
    return _person(request, person_id)


@router.delete("/api/persons/{person_id}/bones", responses=error_responses(NotFound))
async def delete_bones(request: Request, person_id: int) -> dict[str, object]:
    """Forget the set lengths: fusion goes back to the online estimate."""
    if not _pipeline(request).set_bone_lengths(person_id, None):
        raise NotFound(f"no person with id {person_id}")
    return _person(request, person_id)


@router.put("/api/bones/default", responses=error_responses(InvalidRequest))
async def put_default_bones(request: Request, body: BoneLengths) -> dict[str, object]:
    """Lengths every new person starts with (as ``set``); existing persons are unchanged."""
    lengths = _validated(body)
    _pipeline(request).set_default_bone_lengths(lengths)
    return {"default": _by_name(lengths)}


@router.delete("/api/bones/default")
async def delete_default_bones(request: Request) -> dict[str, object]:
    """New persons go back to online estimation."""
    _pipeline(request).set_default_bone_lengths(None)
    return {"default": None}


@router.get("/api/fusion/settings")
async def get_fusion_settings(request: Request) -> dict[str, object]:
    """The fusion settings in use (docs/fusion.md §9), by name."""
    return {"fusion": fusion_settings_as_dict(_pipeline(request).settings)}
