"""The accuracy benchmark's scenarios: CMU mocap walks (when the data is present) and
procedural people, each with its sensor count and the report group it belongs to."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from skelfuse.agent.sim.mocap import load_asf_amc, load_bvh
from skelfuse.agent.sim.performer import ClipPerformer, Performer, ProceduralPerformer
from skelfuse.agent.sim.scenarios import Line, LineWalkers, Segment

CMU_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu-mocap"


@dataclass
class Scenario:
    """Who moves (``performer``, world frame) for how long, seen by how many sensors.

    ``group`` is the report row the scenario counts towards.
    """

    name: str
    performer: Performer
    duration_s: float
    sensors: int
    group: str


def scenarios(quick: bool) -> list[Scenario]:
    """Every scenario of the benchmark (``quick``: a subset); CMU walks when the data is there."""
    out: list[Scenario] = []
    routine = ProceduralPerformer(1)
    # The routine of person 0: walk 0–6.3 s, turn 6.3–14.3 s, arms 14.3–20.3 s, squats 20.3–26.3 s.
    if (CMU_DIR / "scaled_131_01.bvh").is_file():
        walk = load_bvh(CMU_DIR / "scaled_131_01.bvh")
        walk02 = load_asf_amc(CMU_DIR / "02.asf", CMU_DIR / "02_01.amc")
        for heading_deg in (0,) if quick else (0, 120):
            out.append(Scenario(f"CMU 131_01 start-walk-stop, heading {heading_deg}°",
                                ClipPerformer(walk, heading_rad=math.radians(heading_deg)),
                                walk.duration_s, 3, "CMU walks, 3 sensors"))  # fmt: skip
        if not quick:
            out.append(Scenario("CMU 02_01 walk, heading 60°",
                                ClipPerformer(walk02, heading_rad=math.radians(60)),
                                2 * walk02.duration_s, 3, "CMU walks, 3 sensors"))  # fmt: skip
    out.append(Scenario("walking a circle", Segment(routine, 0.0, 6.3), 6.3, 3,
                        "walking a circle, 3 sensors"))  # fmt: skip
    out.append(Scenario("turning on the spot", Segment(routine, 6.3, 8.0), 8.0, 2,
                        "turning away, 2 sensors"))  # fmt: skip
    if not quick:
        out.append(Scenario("arm raises", Segment(routine, 14.3, 6.0), 6.0, 3,
                            "arm raises, 3 sensors"))  # fmt: skip
        out.append(Scenario("squats", Segment(routine, 20.3, 6.0), 6.0, 4,
                            "squats, 4 sensors"))  # fmt: skip
    crossing = LineWalkers(
        [
            Line((-1.6, 0.2), (1.6, -0.2), speed_mps=1.1),
            Line((1.6, 0.2), (-1.6, -0.2), speed_mps=1.0, height_m=1.62),
        ]
    )
    out.append(Scenario("two people crossing", crossing, 10.0, 3, "2 people crossing, 3 sensors"))
    if not quick:
        occluding = LineWalkers([
            Line((0.0, 0.9), (0.0, 1.0), speed_mps=0.05, pause_s=1.5, arms=True),
            Line((-1.8, 0.0), (1.8, 0.0), speed_mps=0.9, height_m=1.85),
            Line((0.9, -1.2), (-0.9, 1.0), speed_mps=0.8, height_m=1.62, t0_s=2.0),
        ])  # fmt: skip
        out.append(Scenario("one person occluding others", occluding, 10.0, 4,
                            "3 people, occlusion, 4 sensors"))  # fmt: skip
        out.append(Scenario("two people, built-in routine", ProceduralPerformer(2), 16.0, 4,
                            "2 people routine, 4 sensors"))  # fmt: skip
    return out
