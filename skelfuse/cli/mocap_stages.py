"""The stages of ``skelfuse mocap`` (:mod:`skelfuse.cli.mocap`): detection in the mono
environment with progress, then bodies, synchronisation, offline fusion and the exports.

Imports of the recording, fusion and calibration layers happen inside the functions, as in
every command module, so ``skelfuse --help`` stays light.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import logging
import os
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skelfuse.cli.values import UsageError

if TYPE_CHECKING:
    from skelfuse.calibration.camera import Camera
    from skelfuse.fusion.settings import HubSettings
    from skelfuse.recording.take import Take
    from skelfuse.recording.video_take import CameraTrack, MocapSettings, VideoLandmarks

logger = logging.getLogger("skelfuse")
DEFAULT_FOV_DEG = 60.0
MIN_SYNC_CONFIDENCE = 0.2
"""Below this the motion did not pin a video's clock offset down (calibration.motion_sync)."""


class MocapFailed(Exception):
    """The take cannot be made from these inputs; the message says why (exit status 1)."""


def read_landmarks_file(path: Path, names: Sequence[str]) -> list[VideoLandmarks]:
    from skelfuse.recording.video_take import read_landmarks

    try:
        return read_landmarks(path, names)
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: not a landmarks file for these videos ({exc})") from exc


def mono_python(explicit: str | None) -> Path:
    """The Python that has mediapipe: ``--mono-python``, ``$SKELFUSE_MONO_PYTHON``, this one if
    it imports mediapipe, else the project's ``.venv-mono`` (``$SKELFUSE_VENV_MONO``).

    Raises:
        MocapFailed: none found; the message says how to make one.
    """
    candidates: list[Path] = []
    if explicit:
        candidates.append(Path(explicit))
    elif os.environ.get("SKELFUSE_MONO_PYTHON"):
        candidates.append(Path(os.environ["SKELFUSE_MONO_PYTHON"]))
    else:
        if importlib.util.find_spec("mediapipe") and importlib.util.find_spec("cv2"):
            return Path(sys.executable)
        root = Path(__file__).resolve().parents[2]
        venv = Path(os.environ.get("SKELFUSE_VENV_MONO") or root / ".venv-mono")
        inside = Path("Scripts", "python.exe") if os.name == "nt" else Path("bin", "python")
        candidates.append((venv if venv.is_absolute() else root / venv) / inside)
    for candidate in candidates:
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    raise MocapFailed(
        "detection needs mediapipe, which lives in its own environment (numpy<2): make it with "
        "`bash scripts/venv_mono.sh`, or pass --mono-python PATH, or --landmarks FILE "
        f"(looked for {', '.join(map(str, candidates))})"
    )


def detect_landmarks(
    args: argparse.Namespace, videos: Sequence[Path], output: Path
) -> list[VideoLandmarks]:
    """Run the detection stage in the mono environment, with progress on stderr."""
    from skelfuse.cli.mocap_progress import Progress

    python = mono_python(args.mono_python)
    worker = Path(__file__).with_name("mocap_detect.py")  # by path: needs no skelfuse there
    with tempfile.TemporaryDirectory(prefix="skelfuse-mocap-") as tmp:
        target = (
            output.with_suffix(".landmarks.npz") if args.keep_landmarks else Path(tmp) / "l.npz"
        )
        log_path = Path(tmp) / "detect.log"
        command = [str(python), str(worker), "--out", str(target), *map(str, videos)]
        progress = Progress("detecting", sys.stderr)
        error: str | None = None
        with open(log_path, "w+", encoding="utf-8", errors="replace") as log:
            # MediaPipe's own logging (TensorFlow Lite, absl) goes to the log, shown on a crash.
            with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log, text=True) as child:
                assert child.stdout is not None
                for raw in child.stdout:
                    message = _message(raw)
                    if "error" in message:
                        error = str(message["error"])
                    elif "total" in message:
                        progress.set_total(int(message["video"]), int(message["total"]))
                    elif "done" in message:
                        progress.update(int(message["video"]), int(message["done"]))
                status = child.wait()
            progress.finish()
            log.seek(0)
            tail = log.read()[-2000:]
        if error is not None:
            raise MocapFailed(error)
        if status != 0:
            raise MocapFailed(
                f"the detection stage ({python}) failed with status {status}:\n{tail}"
            )
        if args.keep_landmarks:
            logger.info("landmarks kept in %s (--landmarks reuses them)", target)
        return read_landmarks_file(target, [v.stem for v in videos])


def _message(raw: str) -> dict[str, Any]:
    try:
        message = json.loads(raw)
    except json.JSONDecodeError:
        return {}
    return message if isinstance(message, dict) else {}


def fuse_and_export(
    args: argparse.Namespace,
    landmarks: Sequence[VideoLandmarks],
    calibrated: dict[str, Camera] | None,
    output: Path,
) -> None:
    """Bodies → recording → offline fusion → BVH and C3D."""
    from skelfuse.cli.values import fusion_settings
    from skelfuse.protocol.recording_file import write_recording
    from skelfuse.recording.video_take import MocapSettings, place_video, video_recording
    from skelfuse.server.settings import Settings

    settings = MocapSettings(floor=None) if args.no_floor else MocapSettings()
    rates = {v.name: v.fps or args.video_fps or 30.0 for v in landmarks}
    if any(v.fps is None for v in landmarks) and args.video_fps is None:
        logger.warning("the videos' frame rate is unknown: 30 fps assumed (--video-fps)")
    if calibrated is None:
        camera, track = _uncalibrated(args, landmarks[0], settings)
        cameras, tracks = {camera.name: camera}, [track]
    else:
        cameras = calibrated
        tracks = [place_video(v, cameras[v.name], settings=settings) for v in landmarks]
    for track in tracks:
        fixed = track.floor_scales != 1.0
        if fixed.any():
            logger.info(
                "%s: distance from the floor in %d of %d frames (median factor %.3f)",
                track.name,
                int(fixed.sum()),
                track.floor_scales.size,
                float(_median(track.floor_scales[fixed])),
            )
    offsets = _sync(landmarks, cameras, rates) if len(landmarks) > 1 and not args.no_sync else {}
    header, records = video_recording(tracks, cameras, rates, offsets, name=output.stem)
    fps = args.fps or max(rates.values())
    fusion = fusion_settings(args.fusion_config)  # UsageError on a bad file
    replay_settings = dataclasses.replace(Settings(fusion=fusion), output_hz=fps)
    with tempfile.TemporaryDirectory(prefix="skelfuse-mocap-") as tmp:
        path = Path(tmp) / "take.sfrec"
        write_recording(path, header, records)
        frames = sum(record.kind == "frame" for record in records)
        take = _fuse(path, replay_settings, frames)
    _export(take, output, fps, args.bvh_stretch)


def _sync(
    landmarks: Sequence[VideoLandmarks], cameras: dict[str, Camera], rates: dict[str, float]
) -> dict[str, float]:
    """Each video's clock offset (seconds) from the motion (:mod:`calibration.motion_sync`), the
    first video the reference; 0 where the motion does not pin it down."""
    import numpy as np

    from skelfuse.calibration.errors import CalibrationError
    from skelfuse.calibration.motion_sync import lags_from_epipolar

    if len(set(rates.values())) != 1:
        logger.warning("videos at different frame rates: not synchronised (offsets 0)")
        return {}
    frames = max(v.frames for v in landmarks)
    pixels = np.full((len(landmarks), frames, 33, 2), np.nan)
    weights = np.zeros((len(landmarks), frames, 33))
    for k, video in enumerate(landmarks):
        pixels[k, : video.frames] = video.image_px[..., :2]
        weights[k, : video.frames] = np.where(video.detected[:, None], video.visibility, 0.0)
    try:
        sync = lags_from_epipolar(
            [cameras[v.name] for v in landmarks],
            pixels,
            np.nan_to_num(weights),
            rate_hz=next(iter(rates.values())),
        )
    except CalibrationError as exc:
        logger.warning("clocks not synchronised from the motion (%s): offsets 0", exc)
        return {}
    offsets = {}
    for video in landmarks:  # the estimate names cameras; the recording, videos
        camera = cameras[video.name].name
        lag = sync.lag_s[camera]
        trusted = sync.confidence[camera] >= MIN_SYNC_CONFIDENCE
        offsets[video.name] = lag if trusted else 0.0
        logger.info(
            "%s: clock %+.1f ms (%+.2f frames, confidence %.2f)%s",
            video.name,
            lag * 1000,
            sync.lag_frames[camera],
            sync.confidence[camera],
            "" if trusted else ": not trusted, 0 used",
        )
    return offsets


def _median(values: Sequence[float]) -> float:
    import numpy as np

    return float(np.median(np.asarray(values, dtype=np.float64)))


def _uncalibrated(
    args: argparse.Namespace, video: VideoLandmarks, settings: MocapSettings
) -> tuple[Camera, CameraTrack]:
    """One video without calibration: a level camera, its height from the feet."""
    import numpy as np

    from skelfuse.calibration.camera import Camera, CameraIntrinsics
    from skelfuse.calibration.errors import InvalidInput
    from skelfuse.calibration.floor_depth import level_camera_height
    from skelfuse.geometry.pinhole import Intrinsics
    from skelfuse.recording.video_take import place_video

    width, height = video.size_wh
    try:
        if args.intrinsics:
            pinhole = Intrinsics.parse(args.intrinsics)
        else:
            fov = args.fov if args.fov is not None else DEFAULT_FOV_DEG
            if args.fov is None:
                logger.warning(
                    "no calibration and no --intrinsics: a %.0f° horizontal field of view is "
                    "assumed; distances scale with it (give --fov or --intrinsics)",
                    fov,
                )
            pinhole = Intrinsics.from_fov(width, height, fov)
        intrinsics = CameraIntrinsics(width, height, pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy)
    except (ValueError, InvalidInput) as exc:
        raise UsageError(str(exc)) from exc
    level = Camera(video.name, intrinsics, np.eye(4))
    track = place_video(video, level, floor=None, settings=settings)
    try:
        camera_height = level_camera_height(track.landmarks_cv)
    except InvalidInput as exc:
        raise MocapFailed(f"{video.name}: {exc}") from exc
    pose = np.eye(4)
    pose[1, 3] = camera_height  # the sensor frame is +Y up: a level camera is a lift
    logger.info(
        "%s: a level camera %.2f m above the floor (from the feet)", video.name, camera_height
    )
    return Camera(video.name, intrinsics, pose), track


def _fuse(path: Path, settings: HubSettings, frames_in: int) -> Take:
    """The recording fused offline, with progress; the take."""
    from skelfuse.cli.mocap_progress import Progress
    from skelfuse.recording.replay import ReplayStats, replay
    from skelfuse.recording.take import take_from_frames

    stats = ReplayStats()
    progress = Progress("fusing", sys.stderr)
    progress.set_total(0, frames_in)
    frames = []
    for frame in replay(path, settings, stats=stats):
        frames.append(frame)
        progress.update(0, stats.frames_in)
    progress.update(0, frames_in)
    progress.finish()
    take = take_from_frames(frames)
    if not take.persons:
        raise MocapFailed("no person was fused from these videos (are the cameras calibrated?)")
    return take


def _export(take: Take, output: Path, fps: float, stretch: bool) -> None:
    from skelfuse.recording.export_bvh import export_bvh
    from skelfuse.recording.export_c3d import export_c3d
    from skelfuse.recording.take import TakeError

    c3d = output.with_suffix(".c3d")
    try:
        track = take.main_person()
        result = export_bvh(track, output, fps=fps, stretch=stretch)
        frames = export_c3d(take, c3d, fps=fps)
    except TakeError as exc:
        raise MocapFailed(str(exc)) from exc
    rig = "stretch" if stretch else "rigid"
    logger.info("wrote %s (%s, %d frames at %g fps) and %s (%d frames)", output, rig,
                result.frames, fps, c3d, frames)  # fmt: skip
