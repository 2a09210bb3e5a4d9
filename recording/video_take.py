"""Videos' pose landmarks → a skelfuse recording, so ``skelfuse mocap`` fuses them like any take.

Each video is one ``rgb`` sensor named after its file stem. Per frame, MediaPipe's landmarks
(read from the detection stage's file, :func:`read_landmarks`) become one body exactly as the
live ``mono`` source makes it (:mod:`skelfuse.protocol.mediapipe_pose`): PnP placement in the
camera, states from visibility, the 25 joints in the sensor frame. With a calibrated camera two
things are added before the mapping:

- the image landmarks are undistorted with the calibration's lens model first;
- the body's distance comes from the floor where a foot stands on it
  (:mod:`skelfuse.calibration.floor_depth`), PnP's elsewhere.

The frames are stamped at each video's frame rate from one common start (minus the video's clock
offset, e.g. from synchronisation by motion) and the recording carries every camera's pose as
its calibration, so the offline replay (:mod:`skelfuse.recording.replay`) fuses them. Nothing
reads the wall clock: the same landmarks give the same file.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.camera import SENSOR_FROM_OPENCV, Camera
from skelfuse.calibration.floor import FloorFit
from skelfuse.calibration.floor_depth import FloorDepthSettings, place_on_floor
from skelfuse.geometry.pinhole import Intrinsics
from skelfuse.geometry.pnp import Placement, PnPError
from skelfuse.protocol.mediapipe_pose import (
    LANDMARK_COUNT,
    PlacementMode,
    StatePolicy,
    landmark_states,
    place_landmarks,
    to_kinect_v2,
)
from skelfuse.protocol.recording_file import Header, Record, SensorPose
from skelfuse.protocol.wire import Body, Frame, Hello, encode

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
SENSOR_TYPE = "rgb"
WORLD_FLOOR = FloorFit(np.array([0.0, 1.0, 0.0]), 0.0, 0.0, 0)
"""The project's world floor: y = 0, +Y up (calibration.camera's world)."""
_T0_NS = 1_700_000_000_000_000_000
_NETWORK_DELAY_NS = 2_000_000
_KEYS = ("image_px", "world_m", "visibility", "detected", "size_wh")


@dataclass(frozen=True, slots=True)
class VideoLandmarks:
    """One video's landmarks (the layout of ``tests/data/mono_landmarks.npz``).

    image_px: (F, 33, 3) pixels (x, y, MediaPipe's relative z). world_m: (F, 33, 3) metres,
    hip-centred, OpenCV camera axes. visibility: (F, 33). detected: (F,) bool. size_wh: the
    frames' width and height in pixels. fps: the video's frame rate, or None if unknown.
    """

    name: str
    image_px: FloatArray
    world_m: FloatArray
    visibility: FloatArray
    detected: npt.NDArray[np.bool_]
    size_wh: tuple[int, int]
    fps: float | None

    @property
    def frames(self) -> int:
        return int(self.detected.shape[0])


def read_landmarks(path: str | Path, names: Sequence[str]) -> list[VideoLandmarks]:
    """The named videos' landmarks from a detection file (``<name>_image_px``, ...).

    Raises:
        OSError: the file cannot be read.
        ValueError: a name's arrays are missing or of the wrong shape (the message lists what
            the file holds).
    """
    with np.load(path) as data:
        held = sorted({key.rsplit("_", 2)[0] for key in data.files if key.endswith("_image_px")})
        videos = []
        for name in names:
            missing = [f"{name}_{k}" for k in _KEYS if f"{name}_{k}" not in data.files]
            if missing:
                raise ValueError(f"{path}: no landmarks for {name!r} (it holds {held or 'none'})")
            image = np.asarray(data[f"{name}_image_px"], dtype=np.float64)
            frames = image.shape[0]
            if image.shape != (frames, LANDMARK_COUNT, 3):
                raise ValueError(f"{path}: {name}_image_px is {image.shape}, not (F, 33, 3)")
            fps = float(data[f"{name}_fps"]) if f"{name}_fps" in data.files else None
            width, height = (int(v) for v in data[f"{name}_size_wh"])
            videos.append(
                VideoLandmarks(
                    name,
                    image,
                    np.asarray(data[f"{name}_world_m"], dtype=np.float64).reshape(frames, -1, 3),
                    np.asarray(data[f"{name}_visibility"], dtype=np.float64).reshape(frames, -1),
                    np.asarray(data[f"{name}_detected"], dtype=bool).reshape(frames),
                    (width, height),
                    fps if fps else None,
                )
            )
    return videos


@dataclass(frozen=True, slots=True)
class MocapSettings:
    """How landmarks become bodies: PnP ``mode``, the visibility → state ``policy``, and the
    floor's part in the distance (None: PnP's distance only)."""

    mode: PlacementMode = "pose"
    policy: StatePolicy = field(default_factory=StatePolicy)
    floor: FloorDepthSettings | None = field(default_factory=FloorDepthSettings)


@dataclass(frozen=True, slots=True)
class CameraTrack:
    """One video placed in its camera: what becomes the sensor's frames.

    landmarks_cv: (F, 33, 3) metres, OpenCV camera frame (NaN where no body). joints_m: (F, 25, 3)
    float32, the sensor frame. states: (F, 25) uint8. placed: (F,) bool, a body this frame.
    floor_scales: (F,) the distance factor from the floor (1.0 where PnP's stands).
    """

    name: str
    landmarks_cv: FloatArray
    joints_m: npt.NDArray[np.float32]
    states: npt.NDArray[np.uint8]
    placed: npt.NDArray[np.bool_]
    floor_scales: FloatArray


def _pinhole(video: VideoLandmarks, camera: Camera) -> tuple[FloatArray, Intrinsics]:
    """Undistorted pixels of the landmarks and the pinhole that sees them so."""
    k = camera.intrinsics
    if (k.width, k.height) != video.size_wh:
        logger.warning(
            "%s: video frames are %d×%d, the calibration's %d×%d (used as they are)",
            video.name,
            *video.size_wh,
            k.width,
            k.height,
        )
    xy = camera.normalized(video.image_px[..., :2])
    pixels = np.stack([xy[..., 0] * k.fx + k.cx, xy[..., 1] * k.fy + k.cy], axis=-1)
    return pixels, Intrinsics(k.fx, k.fy, k.cx, k.cy)


def place_video(
    video: VideoLandmarks,
    camera: Camera,
    *,
    floor: FloorFit | None = WORLD_FLOOR,
    settings: MocapSettings = MocapSettings(),
) -> CameraTrack:
    """Every frame's body in the camera (frames without a body or a placement stay empty).

    Args:
        video: its landmarks. camera: its intrinsics and pose (world +Y up).
        floor: the world floor, or None when the camera's pose does not know it (then PnP's
            distance stands everywhere).
        settings: placement, states, floor use.
    """
    pixels, intrinsics = _pinhole(video, camera)
    frames = video.frames
    points = np.full((frames, LANDMARK_COUNT, 3), np.nan)
    placed = np.zeros(frames, dtype=bool)
    previous: Placement | None = None
    for i in np.flatnonzero(video.detected):
        try:
            points[i], previous = place_landmarks(
                pixels[i],
                video.world_m[i],
                video.visibility[i],
                intrinsics,
                settings.mode,
                previous,
            )
        except PnPError:
            previous = None
            continue
        placed[i] = True
    scales = np.ones(frames)
    if floor is not None and settings.floor is not None and placed.any():
        T_world_from_cv = camera.T_world_from_sensor @ SENSOR_FROM_OPENCV
        points, scales = place_on_floor(
            points, T_world_from_cv, floor, visibility=video.visibility, settings=settings.floor
        )
    joints = np.full((frames, 25, 3), np.nan, dtype=np.float32)
    states = np.zeros((frames, 25), dtype=np.uint8)
    for i in np.flatnonzero(placed):
        marks = landmark_states(
            video.visibility[i], video.image_px[i], video.size_wh, settings.policy
        )
        joints[i], states[i] = to_kinect_v2(points[i], marks)
    return CameraTrack(video.name, points, joints, states, placed, scales)


def sensor_id_for(name: str, taken: Iterable[str] = ()) -> str:
    """A valid, unused sensor id for a video's name (the protocol allows letters, digits and
    ``._-``, 64 at most, a letter or digit first): others become ``-``; ``-2``, ``-3`` ... make
    it unique among ``taken``."""
    base = re.sub(r"[^A-Za-z0-9._-]", "-", name)[:60]
    base = base if base[:1].isalnum() else f"v{base}"[:60]
    used = set(taken)
    candidate, n = base, 1
    while candidate in used:
        n += 1
        candidate = f"{base}-{n}"
    return candidate


def video_recording(
    tracks: Sequence[CameraTrack],
    cameras: Mapping[str, Camera],
    fps: Mapping[str, float],
    offsets_s: Mapping[str, float] | None = None,
    *,
    name: str = "mocap",
) -> tuple[Header, list[Record]]:
    """The tracks as one recording: a hello and a frame per video frame per sensor, in time order.

    Args:
        tracks: from :func:`place_video`, one per video (its sensor id: :func:`sensor_id_for`).
        cameras: each track's camera (its pose is the recording's calibration).
        fps: each track's frame rate.
        offsets_s: each track's clock offset in seconds (its frame i was captured at
            ``i / fps - offset``), 0 for a track not named.
        name: the recording's name.

    Raises:
        ValueError: a track without a camera or a frame rate, or a rate that is not positive.
    """
    offsets = offsets_s or {}
    # Shifted frames must not come before the hellos: start late enough for the largest offset.
    start_ns = _T0_NS + round(max([0.0, *offsets.values()]) * 1e9)
    calibration: dict[str, SensorPose] = {}
    sensors: dict[str, dict[str, object]] = {}
    stamped: list[tuple[int, int, Record]] = []
    for k, track in enumerate(tracks):
        if track.name not in cameras or fps.get(track.name, 0.0) <= 0:
            raise ValueError(f"{track.name}: needs a camera and a positive frame rate")
        rate = fps[track.name]
        sensor_id = sensor_id_for(track.name, taken=sensors.keys())
        pose = np.asarray(cameras[track.name].T_world_from_sensor, dtype=np.float64)
        calibration[sensor_id] = SensorPose(pose, "manual", "stored")
        sensors[sensor_id] = {"type": SENSOR_TYPE, "pose_state": "stored", "source": track.name}
        hello = Hello(sensor_id, SENSOR_TYPE, "skelfuse-mocap", rate, _T0_NS)
        stamped.append((_T0_NS, k, Record(_T0_NS, sensor_id, "hello", encode(hello))))
        shift_ns = round(offsets.get(track.name, 0.0) * 1e9)
        for i in range(track.placed.shape[0]):
            t_ns = start_ns + round(i * 1e9 / rate) - shift_ns + k  # +k: unique, stable order
            bodies: tuple[Body, ...] = ()
            if track.placed[i]:
                bodies = (Body(1, track.joints_m[i], track.states[i]),)
            payload = encode(Frame(i + 1, t_ns, bodies))
            t_arrival = t_ns + _NETWORK_DELAY_NS
            stamped.append((t_arrival, k, Record(t_arrival, sensor_id, "frame", payload)))
    stamped.sort(key=lambda r: (r[0], r[1]))
    header = Header(_T0_NS / 1e9, "skelfuse-mocap", name, calibration, sensors)
    return header, [r[2] for r in stamped]
