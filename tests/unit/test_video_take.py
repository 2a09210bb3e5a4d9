"""recording.video_take: stored landmarks of the real clip → placed bodies → a recording that fuses.

Runs on ``tests/data/mono_landmarks.npz`` and the clip's Qualisys calibration: no model needed.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.camera import SENSOR_FROM_OPENCV, Camera
from skelfuse.calibration.camera_files import read_camera_file
from skelfuse.calibration.floor_depth import DEFAULT_CONTACT_HEIGHT_M, MEDIAPIPE_FEET
from skelfuse.protocol.recording_file import write_recording
from skelfuse.protocol.skeleton import JointId, TrackingState
from skelfuse.protocol.wire import Frame, Hello, decode
from skelfuse.recording.replay import replay
from skelfuse.recording.take import take_from_frames
from skelfuse.recording.video_take import (
    MocapSettings,
    VideoLandmarks,
    place_video,
    read_landmarks,
    sensor_id_for,
    video_recording,
)

DATA = Path(__file__).resolve().parents[1] / "data"
CAMERAS = ("cam01", "cam02", "cam03", "cam04")


@pytest.fixture(scope="module")
def videos() -> list[VideoLandmarks]:
    return read_landmarks(DATA / "mono_landmarks.npz", CAMERAS)


@pytest.fixture(scope="module")
def cameras() -> dict[str, Camera]:
    found = read_camera_file(DATA / "pose2sim_single_calib.qca.txt", "qualisys")
    return {c.name: c for c in found.cameras}


def _world(camera: Camera, points_cv: np.ndarray) -> np.ndarray:
    T = camera.T_world_from_sensor @ SENSOR_FROM_OPENCV
    out: np.ndarray = points_cv @ T[:3, :3].T + T[:3, 3]
    return out


def test_landmarks_are_read_by_video_name(videos: list[VideoLandmarks]) -> None:
    assert [v.name for v in videos] == list(CAMERAS)
    assert all(v.frames == 100 and v.detected.all() and v.fps is None for v in videos)
    assert videos[0].size_wh == (1080, 1920)
    with pytest.raises(ValueError, match=r"no landmarks for 'cam09'.*cam01"):
        read_landmarks(DATA / "mono_landmarks.npz", ["cam09"])


def test_the_floor_sets_the_feet_on_it_where_pnp_leaves_them_off(
    videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> None:
    feet = list(MEDIAPIPE_FEET)
    for video in videos:
        camera = cameras[video.name]
        pnp = place_video(video, camera, settings=MocapSettings(floor=None))
        floor = place_video(video, camera)
        assert pnp.placed.all() and floor.placed.all()
        assert (pnp.floor_scales == 1.0).all()
        assert np.isfinite(floor.floor_scales).all() and (floor.floor_scales != 1.0).mean() > 0.9
        lowest_pnp = _world(camera, pnp.landmarks_cv)[:, feet, 1].min(axis=1)
        lowest_floor = _world(camera, floor.landmarks_cv)[:, feet, 1].min(axis=1)
        # On the floor (to the running median's smoothing) where PnP floats or sinks.
        assert abs(np.median(lowest_floor) - DEFAULT_CONTACT_HEIGHT_M) < 0.01, video.name
        assert np.median(np.abs(lowest_floor - DEFAULT_CONTACT_HEIGHT_M)) < np.median(
            np.abs(lowest_pnp - DEFAULT_CONTACT_HEIGHT_M)
        ), video.name


def test_joints_reach_the_wire_in_the_sensor_frame(
    videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> None:
    track = place_video(videos[0], cameras["cam01"])
    head, foot = JointId.HEAD, JointId.FOOT_LEFT
    assert track.joints_m.dtype == np.float32 and track.joints_m.shape == (100, 25, 3)
    assert (track.joints_m[:, head, 1] > track.joints_m[:, foot, 1]).all()  # +Y up
    assert (track.joints_m[:, :, 2][track.states > 0] > 1.0).all()  # in front of the camera
    assert (track.states[:, JointId.SPINE_MID] <= TrackingState.INFERRED).all()


def test_a_frame_without_a_body_stays_empty(
    videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> None:
    video = videos[1]
    detected = video.detected.copy()
    detected[10:20] = False
    gappy = VideoLandmarks(video.name, video.image_px, video.world_m, video.visibility, detected,
                           video.size_wh, 60.0)  # fmt: skip
    track = place_video(gappy, cameras[video.name])
    assert not track.placed[10:20].any() and track.placed[20:].all()
    assert np.isnan(track.joints_m[10:20]).all() and (track.states[10:20] == 0).all()


def test_the_recording_stamps_frames_per_video_clock_and_fuses(
    tmp_path: Path, videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> None:
    tracks = [place_video(v, cameras[v.name]) for v in videos[:2]]
    rates = {"cam01": 60.0, "cam02": 60.0}
    header, records = video_recording(tracks, cameras, rates, {"cam02": 0.05}, name="t")
    assert set(header.calibration) == {"cam01", "cam02"}
    assert header.sensors["cam01"]["type"] == "rgb"
    assert [r.kind for r in records[:2]] == ["hello", "hello"]
    times = [r.t_server_ns for r in records]
    assert times == sorted(times)
    frames: dict[str, list[Frame]] = {"cam01": [], "cam02": []}
    for record in records:
        message = decode(record.payload)
        if isinstance(message, Hello):
            assert message.sensor_type == "rgb" and message.fps == 60.0
        else:
            assert isinstance(message, Frame)
            frames[record.sensor_id].append(message)
    assert [len(f) for f in frames.values()] == [100, 100]
    first = {k: v[0].t_capture_ns for k, v in frames.items()}
    # cam02's frame i was captured 50 ms before cam01's (less the 1 ns that orders the sensors)
    assert first["cam01"] - first["cam02"] == 50_000_000 - 1
    step = frames["cam01"][1].t_capture_ns - frames["cam01"][0].t_capture_ns
    assert abs(step - 1e9 / 60) <= 1.0
    path = tmp_path / "t.sfrec"
    write_recording(path, header, records)
    take = take_from_frames(replay(path))
    person = take.main_person()
    assert person.times_s.size >= 40  # the hub's 30 Hz grid over 1.6 s
    assert np.isfinite(person.joints[:, JointId.HEAD]).all()


def test_a_track_without_camera_or_rate_is_refused(
    videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> None:
    track = place_video(videos[0], cameras["cam01"])
    with pytest.raises(ValueError, match="cam01"):
        video_recording([track], cameras, {"cam01": 0.0})
    with pytest.raises(ValueError, match="cam01"):
        video_recording([track], {}, {"cam01": 60.0})


def test_the_floor_beats_pnp_against_the_four_view_reference(
    videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> None:
    """bench/mono/floor_depth.py's table: the floor's distance is nearer the triangulated reference
    than PnP's on three cameras of four and on average (199 -> 161 mm absolute)."""
    from bench.mono.floor_depth import errors_mm, reference, variants

    ref, lags = reference(videos, cameras)
    assert lags == {"cam01": 0, "cam02": 0, "cam03": 2, "cam04": 0}
    better, pnp_total, floor_total = 0, 0.0, 0.0
    for video in videos:
        lag = lags[video.name]
        truth = np.full_like(ref, np.nan)
        truth[lag:] = ref[: ref.shape[0] - lag]
        found = variants(video, cameras[video.name], ("pnp", "floor"))
        pnp, floor = errors_mm(found["pnp"], truth), errors_mm(found["floor"], truth)
        better += floor["abs_mean"] < pnp["abs_mean"]
        pnp_total += pnp["abs_mean"]
        floor_total += floor["abs_mean"]
    assert better >= 3
    assert floor_total < 0.9 * pnp_total


def test_any_video_name_becomes_a_valid_sensor_id(
    tmp_path: Path, videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> None:
    assert sensor_id_for("cam01") == "cam01"
    assert sensor_id_for("My take (1)") == "My-take--1-"
    assert sensor_id_for("_front", taken=["v_front"]) == "v_front-2"
    assert len(sensor_id_for("x" * 100)) == 60
    track = replace(place_video(videos[0], cameras["cam01"]), name="My take (1)")
    header, records = video_recording(
        [track], {"My take (1)": cameras["cam01"]}, {"My take (1)": 60.0}
    )
    assert set(header.calibration) == {"My-take--1-"}
    path = tmp_path / "named.sfrec"
    write_recording(path, header, records)
    assert take_from_frames(replay(path)).persons  # the hub took the sensor
