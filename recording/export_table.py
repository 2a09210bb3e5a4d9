"""CSV and JSON of fused joint positions with confidences (world frame, +Y up, metres).

CSV: one row per (fused instant, person): ``t_s, person_id``, then for each of the 25 joints
``<Joint>_x, <Joint>_y, <Joint>_z, <Joint>_c`` (Kinect v2 joint names, e.g. ``SpineBase_x``).
An unknown joint has empty x, y, z and c = 0. JSON: the skeleton definition and, per person,
``times_s``, ``joints`` (T × 25 × [x, y, z] or null) and ``confidence`` (T × 25).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.protocol.skeleton import JOINT_NAMES, skeleton_definition
from skelfuse.recording.take import Take


def csv_header() -> list[str]:
    columns = ["t_s", "person_id"]
    for name in JOINT_NAMES:
        columns += [f"{name}_x", f"{name}_y", f"{name}_z", f"{name}_c"]
    return columns


def export_csv(take: Take, path: str | Path, decimals: int = 4) -> int:
    """Write the take as CSV, rows ordered by time then person; returns the row count."""
    rows: list[tuple[float, int, list[str]]] = []
    for person in take.persons.values():
        for t_s, joints, confidence in zip(
            person.times_s, person.joints, person.confidence, strict=True
        ):
            cells: list[str] = [f"{t_s:.6f}", str(person.person_id)]
            for xyz, c in zip(joints, confidence, strict=True):
                if np.isfinite(xyz).all():
                    cells += [f"{v:.{decimals}f}" for v in xyz]
                    cells.append(f"{c:.3f}")
                else:
                    cells += ["", "", "", "0"]
            rows.append((float(t_s), person.person_id, cells))
    rows.sort(key=lambda r: (r[0], r[1]))
    with Path(path).open("w", newline="", encoding="utf-8") as out:
        writer = csv.writer(out)
        writer.writerow(csv_header())
        writer.writerows(r[2] for r in rows)
    return len(rows)


def take_json(take: Take, decimals: int = 4) -> dict[str, Any]:
    persons = []
    for person in take.persons.values():
        rounded = np.round(person.joints, decimals)
        finite = np.asarray(np.isfinite(rounded).all(axis=2), dtype=bool)
        joints = [
            [rounded[t, j].tolist() if finite[t, j] else None for j in range(rounded.shape[1])]
            for t in range(rounded.shape[0])
        ]
        persons.append(
            {
                "id": person.person_id,
                "times_s": [round(float(t), 6) for t in person.times_s],
                "joints": joints,
                "confidence": np.round(person.confidence, 3).tolist(),
            }
        )
    return {"format": "skelfuse-take", "version": 1, "skeleton": skeleton_definition(),
            "persons": persons}  # fmt: skip


def export_json(take: Take, path: str | Path, decimals: int = 4) -> None:
    Path(path).write_text(
        json.dumps(take_json(take, decimals), separators=(",", ":"), allow_nan=False),
        encoding="utf-8",
    )
