"""Pose files (agent/poses/pose_file.py): both formats, the clock, looping, errors by line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from skelfuse.agent.poses.pose_file import FilePoseSource, read_pose_file, write_pose_file
from skelfuse.agent.sources.base import SensorError
from skelfuse.protocol.messages import SensorPose

S = math.sqrt(0.5)
YAW90 = (0.0, S, 0.0, S)  # a quarter turn about +Y


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_relative_csv_is_anchored_at_the_start_and_interpolated(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "head.csv",
        "# a head turning a quarter turn left in one second\n"
        "t_s,px,py,pz,qx,qy,qz,qw\n"
        "\n"
        "0.0,0,1.6,0,0,0,0,1\n"
        f"1.0,1,1.6,0,0,{S},0,{S}\n",
    )
    source = FilePoseSource(read_pose_file(path), start_ns=5_000_000_000, max_gap_s=2.0)
    half = source.pose_at(5_500_000_000)
    assert half is not None
    assert half.position_m == pytest.approx((0.5, 1.6, 0.0))
    angle = math.radians(45) / 2
    assert half.rotation_xyzw == pytest.approx((0, math.sin(angle), 0, math.cos(angle)))
    assert source.pose_at(5_000_000_000) == SensorPose((0.0, 1.6, 0.0), (0.0, 0.0, 0.0, 1.0))


def test_absolute_times_columns_in_any_order_and_offset(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "track.csv",
        "qw,qx,qy,qz,px,py,pz,t_ns\n"
        "1,0,0,0,0,0,0,1700000000000000000\n"
        f"{S},0,{S},0,2,0,0,1700000000100000000\n",
    )
    track = read_pose_file(path)
    assert track.absolute and track.t0_ns == 1_700_000_000_000_000_000
    plain = FilePoseSource(track, clock_ns=lambda: 0)
    mid = plain.pose_at(1_700_000_000_050_000_000)
    assert mid is not None and mid.position_m == pytest.approx((1.0, 0.0, 0.0))
    # The track moved 50 ms later on the agent's clock: its midpoint comes 50 ms later too.
    shifted = FilePoseSource(track, offset_ns=50_000_000)
    later = shifted.pose_at(1_700_000_000_100_000_000)
    assert later is not None and later.position_m == pytest.approx((1.0, 0.0, 0.0))


def test_json_lines(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "track.jsonl",
        '{"t_s": 0, "pose": [0, 1, 0, 0, 0, 0, 1]}\n\n'
        f'{{"t_s": 0.5, "pose": [0, 1, 2, 0, {S}, 0, {S}]}}\n',
    )
    source = FilePoseSource(read_pose_file(path), start_ns=0)
    end = source.pose_at(500_000_000)
    assert end is not None
    assert end.position_m == (0.0, 1.0, 2.0)
    assert end.rotation_xyzw == pytest.approx(YAW90)


def test_outside_the_track_and_in_gaps_there_is_no_pose_and_a_reason(tmp_path: Path) -> None:
    rows = "".join(f"{t},0,0,0,0,0,0,1\n" for t in (0.0, 0.1, 1.0))
    source = FilePoseSource(
        read_pose_file(write(tmp_path, "p.csv", "t_s,px,py,pz,qx,qy,qz,qw\n" + rows)),
        start_ns=0,
    )
    assert source.pose_at(-40_000_000) is not None  # within the 50 ms held at the ends
    assert source.pose_at(-60_000_000) is None
    assert source.last_miss == "before the pose file's first sample"
    assert source.pose_at(500_000_000) is None  # 0.1 → 1.0 is wider than the 0.25 s gap
    assert source.last_miss == "in a gap of the pose file"
    assert source.pose_at(1_100_000_000) is None
    assert source.last_miss == "after the pose file's last sample"


def test_a_looped_track_repeats_every_last_minus_first(tmp_path: Path) -> None:
    rows = "t_s,px,py,pz,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.2,2,0,0,0,0,0,1\n0.4,0,0,0,0,0,0,1\n"
    track = read_pose_file(write(tmp_path, "loop.csv", rows))
    source = FilePoseSource(track, start_ns=0, loop=True)
    for lap in range(3):
        pose = source.pose_at(lap * 400_000_000 + 100_000_000)
        assert pose is not None and pose.position_m == pytest.approx((1.0, 0.0, 0.0))
    once = FilePoseSource(track, start_ns=0)
    assert once.pose_at(900_000_000) is None
    with pytest.raises(SensorError, match="at least two samples"):
        FilePoseSource(read_pose_file(write(tmp_path, "one.csv", rows.split("0.2,")[0])), loop=True)


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("h.csv", "t,px,py,pz,qx,qy,qz,qw\n", r"h.csv:1: header .*unknown \['t'\]"),
        ("m.csv", "t_s,px,py,pz,qx,qy,qz\n", r"m.csv:1: header .*missing \['qw'\]"),
        ("b.csv", "t_s,t_ns,px,py,pz,qx,qy,qz,qw\n", r"b.csv:1: header"),
        ("n.csv", "t_s,px,py,pz,qx,qy,qz,qw\n0,0,0,0,0,0,0\n", r"n.csv:2: 7 values for 8"),
        ("x.csv", "#c\nt_s,px,py,pz,qx,qy,qz,qw\n0,a,0,0,0,0,0,1\n", r"x.csv:3: px 'a' is not"),
        ("f.csv", "t_s,px,py,pz,qx,qy,qz,qw\n0,nan,0,0,0,0,0,1\n", r"f.csv:2: px is nan"),
        ("q.csv", "t_s,px,py,pz,qx,qy,qz,qw\n0,0,0,0,0,0,0,1.01\n", r"q.csv:2: quaternion norm"),
        ("i.csv", "t_ns,px,py,pz,qx,qy,qz,qw\n1.5,0,0,0,0,0,0,1\n", r"i.csv:2: t_ns '1.5' is not"),
        (
            "o.csv",
            "t_s,px,py,pz,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0,0,0,0,0,0,0,1\n",
            r"o.csv:3: time 0.0 is not after",
        ),
        ("e.csv", "# nothing\n", r"e.csv: no samples"),
        ("j.jsonl", '{"t_s": 0, "pose": [0, 0, 0]}\n', r"j.jsonl:1: expected"),
        ("k.jsonl", "\n{oops\n", r"k.jsonl:2: not JSON"),
        (
            "mix.jsonl",
            '{"t_s": 0, "pose": [0,0,0,0,0,0,1]}\n{"t_ns": 5, "pose": [0,0,0,0,0,0,1]}\n',
            r"mix.jsonl:2: t_ns in a file whose times are not t_ns",
        ),
    ],
)
def test_bad_files_say_where(tmp_path: Path, name: str, text: str, message: str) -> None:
    with pytest.raises(SensorError, match=message):
        read_pose_file(write(tmp_path, name, text))


def test_a_missing_file_is_a_sensor_error(tmp_path: Path) -> None:
    with pytest.raises(SensorError, match="pose file"):
        read_pose_file(tmp_path / "absent.csv")


@pytest.mark.parametrize("absolute", [False, True])
def test_a_written_file_reads_back_exactly(tmp_path: Path, absolute: bool) -> None:
    poses = [
        SensorPose((0.1 * k, 1.6, -1 / 3), (0.0, math.sin(k / 7), 0.0, math.cos(k / 7)))
        for k in range(5)
    ]
    times = (
        [1_700_000_000_000_000_000 + k * 10_000_000 for k in range(5)]
        if absolute
        else [k / 90 for k in range(5)]
    )
    path = tmp_path / "written.csv"
    write_pose_file(path, times, poses, absolute=absolute)
    track = read_pose_file(path)
    assert track.absolute == absolute
    assert track.poses == tuple(poses)
    expected = [(t - times[0]) / 1e9 for t in times] if absolute else times
    assert track.times_s == pytest.approx(tuple(expected), abs=0)
