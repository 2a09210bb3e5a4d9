"""``skelfuse mocap VIDEO... -o take.bvh``: videos to character motion, offline, no server.

Three stages, each the product's own:

1. **detection**: MediaPipe pose landmarks of every frame. MediaPipe pins numpy<2, so it runs in
   its own environment (``scripts/venv_mono.sh`` makes ``.venv-mono``) as a child process
   (:mod:`skelfuse.cli.mocap_detect`) that writes the landmarks to a file and reports progress;
   ``--landmarks FILE`` uses a file made earlier instead (``--keep-landmarks`` keeps one).
2. **bodies**: per video, the ``mono`` source's landmarks → 25 joints, with the distance from
   the floor where the calibration gives it (:mod:`skelfuse.recording.video_take`), written as
   a recording of ``rgb`` sensors with the cameras' poses as its calibration.
3. **fusion and export**: the offline replay (:mod:`skelfuse.recording.replay`) fuses the
   cameras as the server would, then the BVH exporter and the C3D exporter write the take.

Cameras: ``--calibration FILE`` (Qualisys ``.qca.txt``, Pose2Sim ``.toml``, OpenCV YAML/XML;
:mod:`skelfuse.calibration.camera_files`) names each camera; a video goes with the camera of
its file stem (``cam01.mp4`` ↔ ``cam01``), or by order when no name matches. One video may go
without: a level camera, intrinsics from ``--intrinsics`` or a field of view (``--fov``), its
height from the feet.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.cli.mocap_stages import (
    DEFAULT_FOV_DEG,
    MocapFailed,
    detect_landmarks,
    fuse_and_export,
    read_landmarks_file,
)
from skelfuse.cli.values import UsageError

if TYPE_CHECKING:
    from skelfuse.calibration.camera import Camera
    from skelfuse.calibration.camera_files import Format

logger = logging.getLogger("skelfuse")
CALIBRATION_FORMATS: dict[str, Format] = {
    ".toml": "pose2sim",
    ".yml": "opencv",
    ".yaml": "opencv",
    ".xml": "opencv",
}


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``mocap`` to the command line."""
    mocap = sub.add_parser(
        "mocap",
        help="videos to character motion: a BVH and a C3D, offline (no server)",
        description="Detect the person in each video, place and fuse the cameras, write a BVH "
        "and a C3D beside it. Detection needs the mono environment (scripts/venv_mono.sh).",
    )
    mocap.add_argument("videos", nargs="+", metavar="VIDEO", help="video files, one per camera")
    mocap.add_argument("-o", "--output", required=True, help="the BVH to write (.bvh)")
    mocap.add_argument(
        "--calibration",
        metavar="FILE",
        default=None,
        help="the cameras' calibration: Qualisys .qca.txt, Pose2Sim .toml, OpenCV .yml/.xml",
    )
    mocap.add_argument(
        "--calibration-format",
        choices=("qualisys", "pose2sim", "opencv"),
        default=None,
        help="the calibration file's format (default: from its name)",
    )
    mocap.add_argument(
        "--intrinsics", default=None, help="one uncalibrated video: fx,fy,cx,cy in pixels"
    )
    mocap.add_argument(
        "--fov",
        type=float,
        default=None,
        help="one uncalibrated video: horizontal field of view, degrees (default "
        f"{DEFAULT_FOV_DEG:g}, with a warning: every distance scales with it)",
    )
    mocap.add_argument(
        "--no-sync",
        action="store_true",
        help="take the videos as started together (no clock offsets from the motion)",
    )
    mocap.add_argument(
        "--no-floor", action="store_true", help="keep PnP's distance (no depth from the floor)"
    )
    mocap.add_argument(
        "--fps", type=float, default=None, help="output frame rate (default: the videos')"
    )
    mocap.add_argument(
        "--video-fps",
        type=float,
        default=None,
        help="the videos' frame rate when the landmarks file does not say (default 30)",
    )
    mocap.add_argument(
        "--fusion-config",
        default=None,
        metavar="FILE",
        help="fuse with this TOML [fusion] table's settings (docs/fusion.md §9)",
    )
    mocap.add_argument(
        "--bvh-stretch",
        action="store_true",
        help="per-frame bone lengths (exact joints) instead of rigid bones",
    )
    mocap.add_argument(
        "--landmarks", metavar="FILE", default=None, help="use these landmarks, skip detection"
    )
    mocap.add_argument(
        "--keep-landmarks",
        action="store_true",
        help="keep the detected landmarks beside the output (OUTPUT.landmarks.npz)",
    )
    mocap.add_argument(
        "--mono-python",
        metavar="PATH",
        default=None,
        help="the Python of the environment with mediapipe (default: $SKELFUSE_MONO_PYTHON, "
        "this one if it has mediapipe, else .venv-mono)",
    )
    mocap.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Make the take; 0, or 1 after an error message (no person, unreadable video, ...).

    Raises:
        UsageError: missing files, bad options.
    """
    try:
        _run(args)
    except MocapFailed as exc:
        print(f"skelfuse: error: {exc}", file=sys.stderr)
        return 1
    return 0


def _run(args: argparse.Namespace) -> None:
    videos = [Path(v) for v in args.videos]
    names = [v.stem for v in videos]
    if len(set(names)) != len(names):
        raise UsageError(f"videos need distinct file names (camera names): {', '.join(names)}")
    output = Path(args.output)
    if output.suffix.lower() != ".bvh":
        raise UsageError(f"-o must name a .bvh file, got {output}")
    if not output.parent.is_dir():
        raise UsageError(f"{output.parent}: no such directory for the output")
    if args.calibration is None and len(videos) > 1:
        raise UsageError("several videos need --calibration FILE: their cameras' poses")
    if args.calibration is not None and (args.intrinsics or args.fov is not None):
        raise UsageError("--intrinsics and --fov are for one video without --calibration")
    if args.calibration is not None and not Path(args.calibration).is_file():
        raise UsageError(f"{args.calibration}: no such calibration file")
    calibrated = _calibration(args, names) if args.calibration else None
    if args.landmarks:
        if not Path(args.landmarks).is_file():
            raise UsageError(f"{args.landmarks}: no such landmarks file")
        landmarks = read_landmarks_file(Path(args.landmarks), names)
    else:
        missing = [str(v) for v in videos if not v.is_file()]
        if missing:
            raise UsageError(f"no such video: {', '.join(missing)}")
        landmarks = detect_landmarks(args, videos, output)
    for video, found in zip(videos, landmarks, strict=True):
        seen = int(found.detected.sum())
        if seen == 0:
            raise MocapFailed(f"{video}: no person found in any of its {found.frames} frames")
        logger.info("%s: a person in %d of %d frames", video.name, seen, found.frames)
    fuse_and_export(args, landmarks, calibrated, output)


def _calibration(args: argparse.Namespace, names: Sequence[str]) -> dict[str, Camera]:
    """Each video's camera from the calibration file, by name or else by order."""
    from skelfuse.calibration.camera_files import read_camera_file
    from skelfuse.calibration.errors import CameraFileError

    path = Path(args.calibration)
    fmt: Format = args.calibration_format or _guess_format(path)
    try:
        found = read_camera_file(path, fmt)
    except CameraFileError as exc:
        raise UsageError(str(exc)) from exc
    for warning in found.warnings:
        logger.warning("%s: %s", path, warning)
    by_name = {camera.name: camera for camera in found.cameras}
    if all(name in by_name for name in names):
        return {name: by_name[name] for name in names}
    if len(found.cameras) == len(names) and not any(name in by_name for name in names):
        logger.warning(
            "video names (%s) are not the calibration's cameras (%s): matched by order",
            ", ".join(names),
            ", ".join(by_name),
        )
        return dict(zip(names, found.cameras, strict=True))
    raise UsageError(
        f"{path}: cameras {', '.join(by_name)}; no camera for video "
        + ", ".join(n for n in names if n not in by_name)
        + " (name each video after its camera, e.g. cam01.mp4)"
    )


def _guess_format(path: Path) -> Format:
    name = path.name.lower()
    if name.endswith((".qca.txt", ".qca")):
        return "qualisys"
    fmt = CALIBRATION_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise UsageError(f"{path}: which calibration format? give --calibration-format")
    return fmt
