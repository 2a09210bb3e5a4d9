"""The accuracy benchmark's scenarios: CMU mocap walks (when the data is present) and
procedural people, each with its sensor count and the report group it belongs to."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.mocap import load_asf_amc, load_bvh
from skelfuse.agent.sim.performer import (
    BodyShape,
    ClipPerformer,
    Performer,
    Pose,
    ProceduralPerformer,
    pose_joints,
)
from skelfuse.agent.sim.scenarios import Line, LineWalkers, Segment

CMU_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "cmu-mocap"


@dataclass
class Scenario:
    """Who moves (``performer``, world frame) for how long, seen by how many sensors.

    ``group`` is the report row the scenario counts towards. ``per_seed``, when set, draws the
    performer and each sensor's start delay (seconds after the first) from the run's seed
    instead: random start positions, headings and sensor start order.
    """

    name: str
    performer: Performer
    duration_s: float
    sensors: int
    group: str
    per_seed: Callable[[np.random.Generator], tuple[Performer, list[float]]] | None = field(
        default=None
    )


class InPlace:
    """One person exercising in place at ``position_xz`` facing ``heading_rad`` (0 faces +Z).

    ``exercise``: ``stand`` (a slight sway), ``squat`` (one squat every 3 s) or ``arms``
    (sideways raises every 3 s); ``delay_s`` standing still before it starts.
    """

    def __init__(
        self,
        position_xz: tuple[float, float],
        heading_rad: float,
        exercise: str,
        delay_s: float = 0.0,
        height_m: float = 1.75,
    ) -> None:
        self._position = position_xz
        self._heading = heading_rad
        self._exercise = exercise
        self._delay = delay_s
        self._shape = BodyShape(height_m)

    @property
    def person_count(self) -> int:
        return 1

    def joints_at(self, t_s: float) -> npt.NDArray[np.float64]:
        t = max(t_s - self._delay, 0.0)
        amount = 0.5 - 0.5 * math.cos(2 * math.pi * t / 3.0) if t_s > self._delay else 0.0
        sway = 0.02 * math.sin(2 * math.pi * 0.3 * t_s)
        pose = Pose(shoulder_abd_l=math.radians(6.0), shoulder_abd_r=math.radians(6.0),
                    elbow_flex_l=math.radians(15.0), elbow_flex_r=math.radians(15.0))  # fmt: skip
        if self._exercise == "squat":
            pose = Pose(hip_flex_l=math.radians(95) * amount, hip_flex_r=math.radians(95) * amount,
                        knee_flex_l=math.radians(110) * amount,
                        knee_flex_r=math.radians(110) * amount,
                        shoulder_flex_l=math.radians(60) * amount,
                        shoulder_flex_r=math.radians(60) * amount,
                        torso_pitch=math.radians(30) * amount)  # fmt: skip
        elif self._exercise == "arms":
            abd = math.radians(6.0 + 154.0 * amount)
            pose = Pose(shoulder_abd_l=abd, shoulder_abd_r=abd,
                        elbow_flex_l=math.radians(15.0) * (1 - amount),
                        elbow_flex_r=math.radians(15.0) * (1 - amount))  # fmt: skip
        x, z = self._position
        joints = pose_joints(self._shape, pose, (x + sway, z), self._heading)
        return joints[np.newaxis]


REAR_SENSOR_POSITION_XZ = (3.0 * math.sin(math.radians(15.0)), 3.0 * math.cos(math.radians(15.0)))
"""Where sensor 1 of the benchmark's 3-sensor rig stands (runner.sensor_poses)."""


def seen_from_behind_first(
    exercise: str, delay_s: float
) -> Callable[[np.random.Generator], tuple[Performer, list[float]]]:
    """A person 0.9–1.4 m in front of sensor 1, their back to it (±35°), legs below its field
    of view; sensor 1 starts first, the other two 2–40 ms later in a random order."""

    def draw(rng: np.random.Generator) -> tuple[Performer, list[float]]:
        sx, sz = REAR_SENSOR_POSITION_XZ
        distance = rng.uniform(0.9, 1.4)
        bearing = math.atan2(-sx, -sz) + math.radians(rng.uniform(-15.0, 15.0))
        position = (sx + distance * math.sin(bearing), sz + distance * math.cos(bearing))
        heading = math.atan2(-sx, -sz) + math.radians(rng.uniform(-35.0, 35.0))
        delays = [0.0, *rng.uniform(0.002, 0.040, size=2).tolist()]
        return InPlace(position, heading, exercise, delay_s), delays

    return draw


def random_start(exercise: str) -> Callable[[np.random.Generator], tuple[Performer, list[float]]]:
    """A person anywhere within 1.3 m of the middle, any heading; sensors start in a random
    order within 0.2 s."""

    def draw(rng: np.random.Generator) -> tuple[Performer, list[float]]:
        radius, angle = 1.3 * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        position = (radius * math.sin(angle), radius * math.cos(angle))
        heading = rng.uniform(0, 2 * math.pi)
        return InPlace(position, heading, exercise), rng.uniform(0.0, 0.2, size=3).tolist()

    return draw


def birth_scenarios(quick: bool) -> list[Scenario]:
    """The birth-labelling scenarios (issue 10): seen from behind first, exercise in place
    started facing away, random starts. Their performer is drawn per seed."""
    out: list[Scenario] = []
    kinds = (("stand", 0.0), ("squat", 1.0)) if quick else (("stand", 0.0), ("squat", 1.0),
                                                            ("arms", 1.0))  # fmt: skip
    for exercise, delay in kinds:
        out.append(Scenario(f"seen from behind first, {exercise}", InPlace((0, 0), 0, "stand"),
                            6.0, 3, "seen from behind first, 3 sensors",
                            seen_from_behind_first(exercise, delay)))  # fmt: skip
    if not quick:
        out.append(Scenario("random start, squat", InPlace((0, 0), 0, "stand"), 6.0, 3,
                            "random start, 3 sensors", random_start("squat")))  # fmt: skip
    return out


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
