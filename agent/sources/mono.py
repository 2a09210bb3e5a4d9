"""The ``mono`` source: one ordinary camera (a webcam or a video file) as a skeleton sensor.

Per frame: MediaPipe Pose finds the person's 33 landmarks (:mod:`.mono_camera`), and
:func:`skelfuse.protocol.mediapipe_pose.body_from_landmarks` places them in the camera frame
with the camera's intrinsics and maps them onto the 25 joints with tracking states. One body
per frame at most (MediaPipe's pose solution follows one person); its tracking id changes when
the person is lost for a frame and found again, as a Kinect's does. ``sensor_type`` ``rgb``: its
fusion prior knows that the depth of such a body is far less certain than its place across the
image (fusion/priors.py).

Timestamps:

- ``--video FILE``: frame i of the file is due at ``anchor + i / fps / speed`` (the file's
  frame rate), the anchor being this PC's clock when the first frame is read, which happens
  once the server has registered the agent (as the replay source does), or ``--start-at``
  (Unix seconds: give several videos of one take the same value so their timelines line up).
  The capture stamp is the due time: the video's own timeline. MediaPipe needs ~30 ms of CPU
  per frame, more than a 60 fps video's 16.7 ms: when a frame's body is ready more than
  :data:`MAX_LAG_S` after its due time (the server drops frames stamped 0.5 s before they
  arrive), the anchor moves forward by that lag (the frame is stamped when it leaves), and a
  warning says once that the timeline is being stretched; a ``--speed`` the detector keeps up
  with (0.5 for 60 fps on such a CPU) avoids that. The first frame's lateness (MediaPipe sets
  its graph up, about a second) moves the anchor without a warning: the timeline starts there.
- ``--camera N``: the PC clock when OpenCV returns the frame (exposure and USB latency are not
  subtracted: a fixed lag the server's clock alignment does not see).

Intrinsics: ``--intrinsics fx,fy,cx,cy`` (pixels); or a camera of a calibration file
(``--calibration``: fitted to the frames' size, the landmarks undistorted with its lens model
before the fit, its pose the pose hint); else a guess from ``--fov`` (horizontal, degrees;
default 60) with a warning, since every distance scales with the focal length.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sources.base import Capture, SensorError, wait_for_due
from skelfuse.agent.sources.mono_camera import (
    Detector,
    FrameReader,
    Landmarks,
    PoseDetector,
    VideoFrames,
)
from skelfuse.geometry.pinhole import Intrinsics
from skelfuse.geometry.pnp import Placement, PnPError
from skelfuse.protocol.mediapipe_pose import (
    MonoBody,
    PlacementMode,
    StatePolicy,
    body_from_landmarks,
)
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body

_log = logging.getLogger(__name__)

DEFAULT_FOV_DEG: Final = 60.0
"""Horizontal field of view assumed without ``--intrinsics`` (a typical webcam's 55-70°)."""
DEFAULT_FPS: Final = 30.0
Undistort = Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]
"""(N, 2) distorted pixels → the pixels an ideal pinhole camera would see."""
LensFor = Callable[[int, int], tuple[Intrinsics, Undistort | None]]
"""Given the frames' width and height: the intrinsics for frames of that size, and the
undistortion of landmark pixels (None when the lens has no distortion)."""
MAX_LAG_S: Final = 0.25
"""A video frame read this late after its due time moves the anchor (half the server's 0.5 s
staleness limit, fusion/sensors.py: the frame must still arrive in time)."""


class MonoSource:
    """One camera through MediaPipe Pose, as a ``rgb`` sensor.

    Args:
        camera: a webcam index (``--camera``), or None.
        video: a video file (``--video``), or None. Exactly one of camera and video.
        intrinsics: the camera's, or None to guess from ``fov_deg`` and the first frame's size.
        lens: instead of ``intrinsics``, what gives the intrinsics (and an undistortion) for the
            first frame's size: a calibration file's camera (``--calibration``, built by the CLI).
        fov_deg: horizontal field of view for that guess.
        pose: ``T_world_from_sensor`` announced as a manual pose hint, or None.
        loop: a video starts again after its last frame.
        speed: a video's playback speed factor.
        start_unix_s: a video's frame 0 at this wall-clock instant (default: when first read).
        policy: visibility → tracking state thresholds.
        placement: ``"pose"`` (rotation and translation, default) or ``"translation"``.
        frames, detector: what reads images and finds landmarks (default: OpenCV and
            MediaPipe; tests pass their own).
        wall_clock_ns, sleep: the clock and the wait (tests pass fakes).

    Raises:
        SensorError: neither or both of camera and video, a video that does not open, OpenCV or
            mediapipe missing, a bad field of view or speed.
    """

    def __init__(
        self,
        *,
        camera: int | None = None,
        video: str | Path | None = None,
        intrinsics: Intrinsics | None = None,
        lens: LensFor | None = None,
        fov_deg: float = DEFAULT_FOV_DEG,
        pose: Matrix4 | None = None,
        loop: bool = False,
        speed: float = 1.0,
        start_unix_s: float | None = None,
        policy: StatePolicy | None = None,
        placement: PlacementMode = "pose",
        frames: FrameReader | None = None,
        detector: Detector | None = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        if (camera is None) == (video is None):
            raise SensorError("the mono source needs exactly one of --camera N and --video FILE")
        if speed <= 0:
            raise SensorError(f"speed must be positive, got {speed}")
        if not 0.0 < fov_deg < 180.0:
            raise SensorError(f"--fov must be in (0, 180) degrees, got {fov_deg}")
        self._is_video = video is not None
        if frames is None:
            frames = VideoFrames(video) if video is not None else VideoFrames(int(camera or 0))
        self._frames = frames
        try:
            self._detector = detector or PoseDetector()
        except SensorError:
            self._frames.close()
            raise
        self._given = intrinsics
        self._lens = lens
        self._intrinsics: Intrinsics | None = None
        self._undistort: Undistort | None = None
        self._fov_deg = fov_deg
        self._pose = pose
        self._loop = loop
        self._speed = speed
        self._policy = policy or StatePolicy()
        self._placement_mode: PlacementMode = placement
        self._clock = wall_clock_ns
        self._sleep = sleep
        self._fps = self._frames.fps or DEFAULT_FPS
        self._period_ns = 1e9 / self._fps / speed
        self._anchor_ns: int | None = None if start_unix_s is None else round(start_unix_s * 1e9)
        self._index = 0  # frames read since the anchor
        self._previous: Placement | None = None
        self._tracking_id = 0
        self._finished = False
        self.frames_read = 0
        """Frames read so far (all loops)."""
        self.frames_with_body = 0
        """Frames in which a body was found and placed."""
        self.reanchors = 0
        """Times a video's timeline was moved forward because detection fell behind."""
        self.last_body: MonoBody | None = None
        """The latest frame's body with its placement (diagnostics), None when none."""

    @property
    def waits_for_server(self) -> bool:
        """A video starts once the server has registered the agent; a camera streams at once."""
        return self._is_video

    @property
    def finished(self) -> bool:
        """A video (not looping) has sent its last frame."""
        return self._finished

    @property
    def sensor_type(self) -> str:
        return "rgb"

    @property
    def fps(self) -> float:
        return self._fps

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None if self._pose is None else (self._pose.copy(), "manual")

    def next_capture(self, timeout_s: float) -> Capture | None:
        """The next frame's body (or none), paced to the video's timeline for files."""
        if self._finished:
            self._sleep(timeout_s)
            return None
        due = 0
        if self._is_video:
            now = self._clock()
            if self._anchor_ns is None:
                self._anchor_ns = now
            due = self._anchor_ns + round(self._index * self._period_ns)
            if not wait_for_due(due, now, timeout_s, self._sleep):
                return None
        image = self._frames.read()
        if image is None and self._is_video and self._loop and self._frames.rewind():
            assert self._anchor_ns is not None
            self._anchor_ns += round(self._index * self._period_ns)
            self._index = 0
            due = self._anchor_ns
            image = self._frames.read()
        if image is None:
            if self._is_video:
                self._finished = True
                return None
            raise SensorError("the camera stopped delivering frames")
        self._index += 1
        self.frames_read += 1
        if not self._is_video:
            t_capture_ns = self._clock()
            return Capture(t_capture_ns=t_capture_ns, bodies=self._bodies(image))
        bodies = self._bodies(image)
        late_ns = self._clock() - due  # the frame leaves now: its stamp must not be stale
        if late_ns > MAX_LAG_S * 1e9:
            if self.frames_read == 1:  # the model's first run (graph set-up): start from here
                assert self._anchor_ns is not None
                self._anchor_ns += late_ns
            else:
                self._fall_behind(late_ns)
            due += late_ns
        return Capture(t_capture_ns=due, bodies=bodies)

    def _fall_behind(self, lag_ns: int) -> None:
        assert self._anchor_ns is not None
        self._anchor_ns += lag_ns
        self.reanchors += 1
        if self.reanchors == 1:
            _log.warning(
                "mono: detection is %.0f ms behind the video at speed %g: moving its timeline "
                "forward (motion looks faster there); a lower --speed keeps the timeline",
                lag_ns / 1e6,
                self._speed,
            )

    def _intrinsics_for(self, width: int, height: int) -> Intrinsics:
        """The intrinsics for frames of this size: decided on the first frame, then kept."""
        if self._intrinsics is not None:
            return self._intrinsics
        if self._lens is not None:
            self._intrinsics, self._undistort = self._lens(width, height)
        elif self._given is not None:
            self._intrinsics = self._given
            k = self._given
            if abs(k.cx - width / 2) > 0.2 * width or abs(k.cy - height / 2) > 0.2 * height:
                # Intrinsics of another resolution or orientation (a portrait phone video with
                # a landscape calibration): every placement would be off, so say it once.
                _log.warning(
                    "mono: the principal point (%.0f, %.0f) px of --intrinsics is far from the "
                    "centre of the %dx%d frames: intrinsics of another size or orientation?",
                    k.cx,
                    k.cy,
                    width,
                    height,
                )
        else:
            self._intrinsics = Intrinsics.from_fov(width, height, self._fov_deg)
            _log.warning(
                "mono: no --intrinsics: guessing fx=fy=%.0f px from a %.0f° field of view; "
                "every distance scales with the focal length, so measure the intrinsics",
                self._intrinsics.fx,
                self._fov_deg,
            )
        return self._intrinsics

    def _bodies(self, frame: npt.NDArray[np.uint8]) -> tuple[Body, ...]:
        found: Landmarks | None = self._detector.detect(frame)
        if found is None:
            self._lost()
            return ()
        height, width = frame.shape[:2]
        intrinsics = self._intrinsics_for(width, height)
        image_px = found.image_px.astype(np.float64)
        if self._undistort is not None:  # the pinhole model needs undistorted pixels
            image_px[:, :2] = self._undistort(image_px[:, :2])
        try:
            body = body_from_landmarks(
                image_px,
                found.world_m,
                found.visibility,
                (width, height),
                intrinsics,
                self._policy,
                self._placement_mode,
                self._previous,
            )
        except PnPError as exc:
            _log.debug("mono: landmarks found but not placed: %s", exc)
            self._lost()
            return ()
        if self._previous is None:
            self._tracking_id += 1
        self._previous = body.placement
        self.last_body = body
        self.frames_with_body += 1
        return (Body(self._tracking_id, body.joints_m, body.states),)

    def _lost(self) -> None:
        self._previous = None
        self.last_body = None

    def close(self) -> None:
        self._detector.close()
        self._frames.close()
