"""``skelfuse agent --source azure_kinect --pose-source ... --reproject`` (skelfuse/cli/
agent_reprojected.py) builds the re-projected source with the pose source's sensor poses as its
``pose_at``, against the fake pykinect_azure (tests/fakes/pykinect_azure)."""

from __future__ import annotations

import importlib
import math
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

from skelfuse.agent.runner import make_hello
from skelfuse.cli import build_parser
from skelfuse.cli.agent import sensor_from_args
from skelfuse.cli.values import UsageError
from skelfuse.protocol.sensor_pose import pose_matrix

FAKES = Path(__file__).resolve().parents[1] / "fakes"


@pytest.fixture
def fake_k4a(monkeypatch: pytest.MonkeyPatch) -> Iterator[ModuleType]:
    monkeypatch.syspath_prepend(str(FAKES))
    for name in [m for m in sys.modules if m.split(".")[0] == "pykinect_azure"]:
        del sys.modules[name]
    k4a = importlib.import_module("pykinect_azure.k4a._k4a")
    k4a.reset()
    yield k4a
    for name in [m for m in sys.modules if m.split(".")[0] == "pykinect_azure"]:
        del sys.modules[name]


def parse(*options: str) -> object:
    return build_parser().parse_args(["agent", "--id", "head-a", *options])


def test_the_reprojected_source_gets_the_sensor_poses(fake_k4a: ModuleType, tmp_path: Path) -> None:
    track = tmp_path / "head.jsonl"
    track.write_text('{"t_s": 0, "pose": [0, 1.6, 0, 0, 0, 0, 1]}\n')
    half = math.radians(20) / 2
    args = parse(
        "--source", "azure_kinect", "--reproject", "--pose-source", f"file:{track}",
        "--pose-space", "room-a", f"--mount=0,0.03,0.09,{math.sin(half)},0,0,{math.cos(half)}",
        "--reference-height-m", "1.5",
    )  # fmt: skip
    source = sensor_from_args(args)  # type: ignore[arg-type]
    try:
        hello = make_hello("head-a", source)
        assert hello.moving and hello.pose_space == "room-a"
        assert hello.sensor_type == "azure_kinect" and hello.pose_hint is None
        pose_at = source._pose_at  # type: ignore[attr-defined]
        pose = pose_at(source._poses.poses._zero_ns)  # type: ignore[attr-defined]
        assert pose is not None
        transform = pose_matrix(pose)
        assert transform[:3, 3] == pytest.approx([0.0, 1.63, 0.09])  # the body's pose × mount
        assert transform[1, 2] == pytest.approx(-math.sin(math.radians(20)))
    finally:
        source.close()
    assert fake_k4a.STARTED[-1] == "closed"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--reproject", "--pose-source", "openvr", "--pose-space", "s"], r"azure_kinect or"),
        (["--source", "femto", "--reproject"], r"--reproject needs --pose-source"),
        (["--reference-height-m", "1.5"], r"--reference-height-m is for --reproject"),
        (
            ["--source", "femto", "--reproject", "--pose-source", "file:x.csv"],
            r"--pose-source file:x.csv: --pose-space is required",
        ),
        (["--source", "azure_kinect", "--reproject", "--wearer", "1"], r"--wearer: only with"),
    ],
)
def test_usage_errors(options: list[str], message: str) -> None:
    with pytest.raises(UsageError, match=message):
        sensor_from_args(parse(*options))  # type: ignore[arg-type]
