"""The ``mono`` source (agent/sources/mono.py) without the model: the real clip's stored landmarks
(tests/data/mono_landmarks.npz) stand in for MediaPipe, blank images for the video, and an
injected clock for time. The real model runs in tests/integration/test_mono_source.py."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.sources.base import SensorError
from skelfuse.agent.sources.mono import MAX_LAG_S, MonoSource
from skelfuse.agent.sources.mono_camera import Landmarks, check_mono
from skelfuse.agent.sources.registry import SOURCE_KINDS, check_sources, make_source
from skelfuse.cli import agent as agent_cli
from skelfuse.cli.values import UsageError
from skelfuse.geometry.pinhole import Intrinsics
from skelfuse.protocol.mediapipe_pose import body_from_landmarks
from skelfuse.protocol.skeleton import JointId, TrackingState

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "mono_landmarks.npz"
CAM = "cam02"
K = Intrinsics(1400.0, 1400.0, 540.0, 960.0)


class BlankFrames:
    """A 60 fps 'video' of ``count`` black portrait frames."""

    def __init__(self, count: int, fps: float | None = 60.0) -> None:
        self.count, self._fps, self.position, self.closed = count, fps, 0, False

    @property
    def fps(self) -> float | None:
        return self._fps

    def read(self) -> npt.NDArray[np.uint8] | None:
        if self.position >= self.count:
            return None
        self.position += 1
        return np.zeros((1920, 1080, 3), np.uint8)

    def rewind(self) -> bool:
        self.position = 0
        return True

    def close(self) -> None:
        self.closed = True


class StoredLandmarks:
    """MediaPipe's real output for the clip, frame after frame; None at ``missing`` calls."""

    def __init__(self, missing: tuple[int, ...] = ()) -> None:
        with np.load(FIXTURE) as data:
            self.image = data[f"{CAM}_image_px"]
            self.world = data[f"{CAM}_world_m"]
            self.visibility = data[f"{CAM}_visibility"]
        self.calls, self.missing = 0, missing

    def detect(self, bgr: npt.NDArray[np.uint8]) -> Landmarks | None:
        assert bgr.shape == (1920, 1080, 3)
        i = self.calls % len(self.image)
        self.calls += 1
        if self.calls - 1 in self.missing:
            return None
        return Landmarks(self.image[i], self.world[i], self.visibility[i])

    def close(self) -> None:
        return None


class Clock:
    def __init__(self, start_ns: int = 1_700_000_000_000_000_000) -> None:
        self.now = start_ns

    def __call__(self) -> int:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += round(seconds * 1e9)


def _source(
    frames: BlankFrames, detector: StoredLandmarks, clock: Clock, **kw: object
) -> MonoSource:
    return MonoSource(
        video="clip.mp4", intrinsics=K, frames=frames, detector=detector,
        wall_clock_ns=clock, sleep=clock.sleep, **kw,  # type: ignore[arg-type]
    )  # fmt: skip


def _drain(source: MonoSource, limit: int = 1000) -> list:  # type: ignore[type-arg]
    captures = []
    for _ in range(limit):
        if source.finished:
            break
        capture = source.next_capture(timeout_s=0.1)
        if capture is not None:
            captures.append(capture)
    return captures


def test_a_video_plays_at_its_pace_from_an_anchor_with_one_body_per_frame() -> None:
    clock = Clock()
    start = clock.now
    source = _source(BlankFrames(10), StoredLandmarks(), clock)
    assert source.sensor_type == "rgb" and source.fps == 60.0 and source.waits_for_server
    captures = _drain(source)
    assert len(captures) == 10 and source.finished
    stamps = np.array([c.t_capture_ns for c in captures]) - start
    np.testing.assert_array_equal(stamps, np.round(np.arange(10) * 1e9 / 60.0))
    assert all(len(c.bodies) == 1 and c.bodies[0].tracking_id == 1 for c in captures)
    assert source.frames_read == source.frames_with_body == 10
    # The body is the pure mapping of the same landmarks (the source adds nothing of its own).
    data = StoredLandmarks()
    first = body_from_landmarks(data.image[0], data.world[0], data.visibility[0], (1080, 1920), K)
    np.testing.assert_array_equal(captures[0].bodies[0].joints_m, first.joints_m)
    np.testing.assert_array_equal(captures[0].bodies[0].states, first.states)
    assert captures[0].bodies[0].states[JointId.NECK] == TrackingState.INFERRED


def test_speed_and_loop_keep_the_timeline_going() -> None:
    clock = Clock()
    start = clock.now
    source = _source(BlankFrames(4), StoredLandmarks(), clock, loop=True, speed=2.0)
    captures = [c for c in (source.next_capture(0.1) for _ in range(40)) if c is not None][:10]
    stamps = np.array([c.t_capture_ns for c in captures]) - start
    np.testing.assert_allclose(stamps, np.arange(10) * 1e9 / 120.0, atol=2)
    assert not source.finished


def test_a_lost_person_comes_back_with_a_new_tracking_id() -> None:
    clock = Clock()
    source = _source(BlankFrames(6), StoredLandmarks(missing=(2, 3)), clock)
    captures = _drain(source)
    assert [len(c.bodies) for c in captures] == [1, 1, 0, 0, 1, 1]
    assert [c.bodies[0].tracking_id for c in captures if c.bodies] == [1, 1, 2, 2]
    assert source.frames_with_body == 4 and source.last_body is not None


def test_without_intrinsics_a_field_of_view_guess_warns(caplog: pytest.LogCaptureFixture) -> None:
    clock = Clock()
    source = MonoSource(
        video="clip.mp4", fov_deg=90.0, frames=BlankFrames(1), detector=StoredLandmarks(),
        wall_clock_ns=clock, sleep=clock.sleep,
    )  # fmt: skip
    capture = source.next_capture(0.1)
    assert capture is not None and len(capture.bodies) == 1
    assert "no --intrinsics" in caplog.text and "fx=fy=540" in caplog.text


def test_bad_arguments_are_refused() -> None:
    frames, detector = BlankFrames(1), StoredLandmarks()
    with pytest.raises(SensorError, match="exactly one"):
        MonoSource(frames=frames, detector=detector)
    with pytest.raises(SensorError, match="exactly one"):
        MonoSource(camera=0, video="x.mp4", frames=frames, detector=detector)
    with pytest.raises(SensorError, match="fov"):
        MonoSource(camera=0, fov_deg=0.0, frames=frames, detector=detector)
    with pytest.raises(SensorError, match="--intrinsics"):
        make_source("mono", {"camera": 0, "intrinsics": "1,2,3"})


def test_registry_doctor_and_command_line_know_mono() -> None:
    assert "mono" in SOURCE_KINDS
    check = next(c for c in check_sources() if c.kind == "mono")
    assert (check.available, check.reason) == check_mono()
    if not check.available:  # the main environment (numpy 2): the reason says what to do
        assert "venv_mono.sh" in check.reason or "numpy" in check.reason
    parser = argparse.ArgumentParser()
    agent_cli.add_parser(parser.add_subparsers())
    args = parser.parse_args(
        ["agent", "--id", "cam-a", "--source", "mono", "--video", "missing.mp4",
         "--intrinsics", "1400,1400,540,960"]
    )  # fmt: skip
    assert (args.video, args.intrinsics, args.camera, args.fov) == (
        "missing.mp4", "1400,1400,540,960", None, None,
    )  # fmt: skip
    with pytest.raises(UsageError, match=r"missing\.mp4|mediapipe|cv2|OpenCV"):
        agent_cli.source_from_args(args)


class SlowDetector(StoredLandmarks):
    """Takes ``cost_s`` of the injected clock per image (``first_s`` for the first), as
    MediaPipe takes CPU time (and sets its graph up on the first image)."""

    def __init__(self, clock: Clock, cost_s: float, first_s: float | None = None) -> None:
        super().__init__()
        self.clock, self.cost_s, self.first_s = clock, cost_s, first_s

    def detect(self, bgr: npt.NDArray[np.uint8]) -> Landmarks | None:
        first = self.calls == 0 and self.first_s is not None
        self.clock.sleep(self.first_s if first else self.cost_s)  # type: ignore[arg-type]
        return super().detect(bgr)


def test_a_detector_slower_than_the_video_moves_the_timeline_not_past_staleness(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = Clock()
    source = _source(BlankFrames(60), SlowDetector(clock, 0.030), clock)  # 30 ms vs 16.7 ms
    stamps, lags = [], []
    for _ in range(60):
        capture = source.next_capture(timeout_s=0.1)
        assert capture is not None
        stamps.append(capture.t_capture_ns)
        lags.append((clock.now - capture.t_capture_ns) / 1e9)  # when it would be sent
    assert source.reanchors >= 2 and "behind the video" in caplog.text
    assert max(lags) < MAX_LAG_S + 0.031  # the server's limit is 0.5 s
    assert (np.diff(stamps) > 0).all()
    # Fast enough (speed 0.5: 33 ms per frame): the timeline is the video's, no moves, also
    # after a slow first frame (the model's set-up), from which the timeline starts silently.
    caplog.clear()
    clock = Clock()
    start = clock.now
    source = _source(BlankFrames(20), SlowDetector(clock, 0.030, 0.9), clock, speed=0.5)
    captures = _drain(source)
    assert source.reanchors == 0 and "behind" not in caplog.text
    stamps_ns = np.array([c.t_capture_ns for c in captures]) - start - round(0.9e9)
    np.testing.assert_array_equal(stamps_ns, np.round(np.arange(20) * 2e9 / 60.0))


def test_start_at_anchors_a_video_to_a_shared_instant() -> None:
    clock = Clock()
    start_s = clock.now / 1e9 + 2.0
    source = _source(BlankFrames(3), StoredLandmarks(), clock, start_unix_s=start_s)
    captures = _drain(source)
    assert captures[0].t_capture_ns == round(start_s * 1e9)
    assert clock.now >= captures[0].t_capture_ns  # it waited for the instant


def test_intrinsics_of_another_frame_size_are_warned_about(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = Clock()
    landscape = Intrinsics(1400.0, 1400.0, 960.0, 540.0)  # a 1920x1080 calibration
    source = MonoSource(
        video="clip.mp4", intrinsics=landscape, frames=BlankFrames(2), detector=StoredLandmarks(),
        wall_clock_ns=clock, sleep=clock.sleep,
    )  # fmt: skip
    _drain(source)
    assert caplog.text.count("centre of the 1080x1920 frames") == 1
    caplog.clear()
    _drain(_source(BlankFrames(2), StoredLandmarks(), Clock()))
    assert "centre of the" not in caplog.text
