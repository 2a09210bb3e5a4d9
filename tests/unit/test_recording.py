"""Recording format, recorder, offline replay and the agent's replay source."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from bench.recording.replay import generate_recording
from skelfuse.protocol.feed import frame_json
from skelfuse.protocol.recording_file import (
    Header,
    Record,
    RecordingError,
    RecordingReader,
    RecordingTruncated,
    SensorPose,
    read_recording,
    summarize,
    write_recording,
)
from skelfuse.protocol.wire import Frame, Hello, decode, encode
from skelfuse.recording.recorder import Recorder
from skelfuse.recording.replay import replay, write_jsonl


@pytest.fixture(scope="module")
def sim_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "sim.sfrec"
    generate_recording(path, sensors=3, persons=2, duration_s=4.0, seed=3)
    return path


def _digest(path: Path) -> list[str]:
    return [
        json.dumps(frame_json(f, include_raw=False), separators=(",", ":")) for f in replay(path)
    ]


def test_replay_is_deterministic_and_fuses_both_people(sim_recording: Path) -> None:
    first = _digest(sim_recording)
    assert first == _digest(sim_recording)
    assert len(first) > 100
    persons = {p["id"] for line in first[-30:] for p in json.loads(line)["persons"]}
    assert len(persons) == 2


def test_header_keeps_calibration(tmp_path: Path) -> None:
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 1.0, 3.0)
    header = Header(1.5, "0.1.0", "take 1", {"k1": SensorPose(pose, "manual", "stored")},
                    {"k1": {"type": "kinect_v2"}})  # fmt: skip
    path = tmp_path / "h.sfrec"
    write_recording(path, header, [Record(5, "k1", "frame", b"x")])
    read, records = read_recording(path)
    np.testing.assert_array_equal(read.calibration["k1"].T_world_from_sensor, pose)
    assert read.name == "take 1" and records == [Record(5, "k1", "frame", b"x")]


def test_truncated_recording_is_readable_up_to_the_last_record(
    sim_recording: Path, tmp_path: Path
) -> None:
    data = sim_recording.read_bytes()
    cut = tmp_path / "cut.sfrec"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with RecordingReader(cut) as reader:
        count = sum(1 for _ in reader.records())
        assert reader.status.truncated and not reader.status.complete
        assert "truncated" in reader.status.describe()
    assert count > 0
    with pytest.raises(RecordingTruncated, match=rf"{count} records"):
        read_recording(cut, strict=True)
    assert len(list(replay(cut))) > 10  # the readable part still replays


def test_corrupt_or_foreign_files_fail_clearly(sim_recording: Path, tmp_path: Path) -> None:
    data = bytearray(sim_recording.read_bytes())
    with RecordingReader(sim_recording) as reader:
        start = reader.status.bytes_read  # where the first record begins
    data[start : start + 4] = b"\xc1" * 4  # 0xc1 is never valid msgpack
    bad = tmp_path / "bad.sfrec"
    bad.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="readable records"):
        read_recording(bad)
    foreign = tmp_path / "foreign.sfrec"
    foreign.write_text("hello")
    with pytest.raises(RecordingError, match="not a skelfuse recording"):
        read_recording(foreign)
    with pytest.raises(RecordingError, match="cannot open"):
        read_recording(tmp_path / "missing.sfrec")


def test_recorder_writes_what_it_is_given_from_any_thread(tmp_path: Path) -> None:
    path = tmp_path / "live.sfrec"
    recorder = Recorder(path, Header(100.0, "0.1.0"), flush_interval_s=0.01)
    hello = encode(Hello("k1", "sim", "0.1.0", 30.0, 0))
    recorder.on_hello("k1", hello, 100.0)

    def frames(sensor: str) -> None:
        for i in range(1, 51):
            recorder.on_frame(sensor, encode(Frame(i, i, ())), 100.0 + i / 30)

    threads = [threading.Thread(target=frames, args=(s,)) for s in ("k1", "k2")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    stats = recorder.close()
    assert stats.records == 101 and stats.frames == 100 and stats.error is None
    _header, records = read_recording(path, strict=True)
    assert len(records) == 101 and records[0].payload == hello
    assert all(isinstance(decode(r.payload), Frame) for r in records[1:])
    summary = summarize(path)
    assert summary.complete and summary.sensors == ("k1", "k2") and summary.frames == 100
    recorder.close()  # idempotent
    recorder.on_frame("k1", b"late", 200.0)  # ignored once closed
    with pytest.raises(RecordingError, match="cannot create"):
        Recorder(path, Header(0, "x"))  # never overwrites


def test_unclosed_recorder_file_is_still_readable(tmp_path: Path) -> None:
    path = tmp_path / "crash.sfrec"
    recorder = Recorder(path, Header(0.0, "0.1.0"), flush_interval_s=0.01)
    recorder.on_frame("k1", encode(Frame(1, 1, ())), 1.0)
    recorder._wake.acquire()  # let the writer thread flush, as after 0.5 s in the server
    recorder._wake.notify()
    recorder._wake.release()
    import time

    deadline = time.monotonic() + 5
    while recorder.stats().bytes_written > path.stat().st_size and time.monotonic() < deadline:
        time.sleep(0.01)
    with RecordingReader(path) as reader:  # as if the server had died here
        assert len(list(reader.records())) == 1 and not reader.status.complete
    recorder.close()


def test_jsonl_has_the_skeleton_then_frames(sim_recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "fused.jsonl"
    with out.open("w") as handle:
        count = write_jsonl(replay(sim_recording), handle)
    lines = out.read_text().splitlines()
    assert json.loads(lines[0])["type"] == "skeleton" and len(lines) == count + 1


def test_replay_source_plays_one_sensor_at_recorded_pace(sim_recording: Path) -> None:
    from skelfuse.agent.sources.base import SensorError
    from skelfuse.agent.sources.replay import ReplaySource

    with pytest.raises(SensorError, match="--sensor"):
        ReplaySource(sim_recording)
    now = [5_000_000_000_000_000_000]

    def sleep(s: float) -> None:
        now[0] += round(s * 1e9)

    source = ReplaySource(sim_recording, "sim-2", loop=True, wall_clock_ns=lambda: now[0],
                          sleep=sleep)  # fmt: skip
    assert source.sensor_type == "replay" and source.pose_hint() is not None
    _, records = read_recording(sim_recording)
    recorded = [f for r in records if r.sensor_id == "sim-2"
                if isinstance(f := decode(r.payload), Frame)]  # fmt: skip
    captures = []
    while len(captures) < source.frame_count + 3:
        capture = source.next_capture(1.0)
        if capture is not None:
            captures.append(capture)
    spacing = np.diff([c.t_capture_ns for c in captures[: source.frame_count]])
    np.testing.assert_array_equal(spacing, np.diff([f.t_capture_ns for f in recorded]))
    assert captures[0].bodies[0].tracking_id == recorded[0].bodies[0].tracking_id
    assert captures[source.frame_count].t_capture_ns > captures[source.frame_count - 1].t_capture_ns
