"""``skelfuse`` subcommands for recordings, exports and sensor checks, and agent sources.

``register(subparsers)`` adds ``replay``, ``export`` and ``doctor``;
``add_source_arguments(parser)`` and ``source_from_args(args)`` give ``skelfuse agent`` every
source kind. Heavy imports stay inside the functions (an agent-only install has no server).
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from skelfuse.agent.sources.base import SensorError, SkeletonSource
from skelfuse.agent.sources.registry import SOURCE_KINDS
from skelfuse.cli import UsageError as CliError

logger = logging.getLogger("skelfuse")
EXPORT_FORMATS = ("bvh", "csv", "json", "c3d")


def _parse_pose(text: str | None) -> Any:
    if text is None:
        return None
    from skelfuse.cli import parse_pose
    from skelfuse.protocol.transform import pose_from_position_yaw_pitch

    position, yaw, pitch = parse_pose(text)
    return pose_from_position_yaw_pitch(position, yaw, pitch)


# --- agent sources ----------------------------------------------------------------------------


def add_source_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of the non-sim sources (``--source`` itself is defined by ``skelfuse agent``)."""
    parser.add_argument("--file", default=None, help="replay: a .sfrec recording; ntu: a .skeleton")
    parser.add_argument("--sensor", default=None, help="replay: which recorded sensor to play")
    parser.add_argument("--loop", action="store_true", help="replay/ntu: start again at the end")
    parser.add_argument("--speed", type=float, default=1.0, help="replay: playback speed factor")
    parser.add_argument(
        "--start-at",
        type=float,
        default=None,
        help="ntu: Unix time of frame 0 (same value for the 3 cameras)",
    )
    parser.add_argument("--device-index", type=int, default=0, help="azure_kinect/femto: device")
    parser.add_argument(
        "--k4a-path",
        default=None,
        help="azure_kinect/femto: k4a library (Orbbec's K4A wrapper for femto)",
    )
    parser.add_argument("--k4abt-path", default=None, help="azure_kinect/femto: k4abt library")
    parser.add_argument(
        "--depth-mode",
        default="NFOV_UNBINNED",
        help="azure_kinect/femto: NFOV_UNBINNED, WFOV_2X2BINNED, ...",
    )


def source_from_args(args: argparse.Namespace) -> SkeletonSource:
    """The source ``skelfuse agent --source KIND ...`` asks for.

    ``sim`` uses ``--pose``, ``--persons``, ``--seed``, ``--clock-offset-ms``; for the real
    sensors and ``ntu``, ``--pose`` is announced as a manual pose hint only when given explicitly
    (``args.pose_given``), since a real sensor's pose is not known by default.
    """
    from skelfuse.agent.sources.registry import make_source

    kind = args.source
    if kind not in SOURCE_KINDS:
        raise CliError(f"unknown source {kind!r}: choose one of {', '.join(SOURCE_KINDS)}")
    pose_text = getattr(args, "pose", None)
    explicit_pose = _parse_pose(pose_text) if getattr(args, "pose_given", True) else None
    options: dict[str, Any] = {
        "file": getattr(args, "file", None),
        "sensor": getattr(args, "sensor", None),
        "loop": getattr(args, "loop", False),
        "speed": getattr(args, "speed", 1.0),
        "start_unix_s": getattr(args, "start_at", None),
        "device_index": getattr(args, "device_index", 0),
        "k4a_path": getattr(args, "k4a_path", None),
        "k4abt_path": getattr(args, "k4abt_path", None),
        "depth_mode": getattr(args, "depth_mode", "NFOV_UNBINNED"),
        "pose": explicit_pose,
    }
    if kind == "sim":
        persons = int(getattr(args, "persons", 2))
        if not 1 <= persons <= 6:
            raise CliError("--persons must be 1..6")
        seed = args.seed if getattr(args, "seed", None) is not None else sum(args.id.encode())
        options.update(
            pose=_parse_pose(pose_text or "0,1.0,3.0,180"),
            persons=persons,
            seed=seed,
            clock_offset_ns=int(getattr(args, "clock_offset_ms", 0.0) * 1e6),
            clock_drift_ppm=float(getattr(args, "clock_drift_ppm", 0.0)),
            send_pose_hint=getattr(args, "pose_hint", True),
        )
    try:
        return make_source(kind, options)
    except SensorError as exc:
        raise CliError(str(exc)) from exc


# --- replay / export / doctor ------------------------------------------------------------------


def register(subparsers: Any) -> None:
    replay = subparsers.add_parser(
        "replay", help="fuse a recording offline (deterministic, faster than real time)"
    )
    replay.add_argument(
        "file", nargs="+", help="a .sfrec recording, or NTU .skeleton files (one per camera)"
    )
    replay.add_argument(
        "--pose",
        action="append",
        default=None,
        help="NTU files: X,Y,Z,YAW_DEG[,PITCH_DEG] per file, in order",
    )
    replay.add_argument("--out", default=None, help="write fused frames as JSON Lines here")
    _fusion_config_option(replay)
    _export_options(replay, required=False)
    replay.set_defaults(func=cmd_replay)

    export = subparsers.add_parser(
        "export", help="export fused motion (from a recording or a fused .jsonl) to a file"
    )
    export.add_argument("file", help="a .sfrec recording or fused frames as .jsonl")
    _fusion_config_option(export)
    _export_options(export, required=True)
    export.set_defaults(func=cmd_export)

    doctor = subparsers.add_parser("doctor", help="which sensor sources can run on this PC")
    doctor.set_defaults(func=cmd_doctor)


def _export_options(parser: argparse.ArgumentParser, required: bool) -> None:
    parser.add_argument(
        "--export", choices=EXPORT_FORMATS, required=required, help="bvh, csv, json or c3d"
    )
    parser.add_argument(
        "--export-path",
        default=None,
        help="output file (default: beside the input, with the format's suffix)",
    )
    parser.add_argument(
        "--person",
        type=int,
        default=None,
        help="bvh: the fused person id (default: the one seen longest)",
    )
    parser.add_argument("--fps", type=float, default=30.0, help="bvh/c3d frame rate")
    parser.add_argument(
        "--bvh-stretch",
        action="store_true",
        help="bvh: per-frame bone lengths (exact joints) instead of rigid bones",
    )


def _recording_path(
    args: argparse.Namespace,
) -> tuple[Path, tempfile.TemporaryDirectory[str] | None]:
    files = [Path(f) for f in args.file] if isinstance(args.file, list) else [Path(args.file)]
    if all(f.suffix == ".skeleton" for f in files):
        from skelfuse.protocol.recording_file import write_recording
        from skelfuse.recording.ntu_import import ntu_recording

        poses = args.pose or []
        if poses and len(poses) != len(files):
            raise CliError(f"give one --pose per NTU file ({len(files)}), or none")
        matrices = [_parse_pose(p) for p in poses] or [None] * len(files)
        if not poses:
            logger.warning(
                "NTU files carry no camera poses: without --pose nothing is fused "
                "(skeleton calibration is a later issue)"
            )
        header, records = ntu_recording(files, matrices)
        tmp = tempfile.TemporaryDirectory(prefix="skelfuse-ntu-")
        path = Path(tmp.name) / "ntu.sfrec"
        write_recording(path, header, records)
        return path, tmp
    if len(files) != 1:
        raise CliError("give one recording (several files only for NTU .skeleton)")
    return files[0], None


def _fusion_config_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--fusion-config",
        default=None,
        metavar="FILE",
        help="a recording: fuse it with this TOML [fusion] table's settings (docs/fusion.md §9)",
    )


def _replay_settings(args: argparse.Namespace) -> Any:
    """Server settings for an offline replay: defaults, or ``--fusion-config``."""
    from skelfuse.cli import fusion_settings
    from skelfuse.server.settings import Settings

    return Settings(fusion=fusion_settings(args.fusion_config))  # CliError on a bad file


def cmd_replay(args: argparse.Namespace) -> int:
    from skelfuse.protocol.recording_file import RecordingError
    from skelfuse.recording.replay import ReplayStats, replay, write_jsonl
    from skelfuse.recording.take import take_from_frames

    path, tmp = _recording_path(args)
    stats = ReplayStats()
    started = time.perf_counter()
    try:
        frames = list(replay(path, _replay_settings(args), stats=stats))
    except RecordingError as exc:
        raise CliError(str(exc)) from exc
    finally:
        if tmp is not None:
            tmp.cleanup()
    elapsed = time.perf_counter() - started
    if args.out:
        with open(args.out, "w", encoding="utf-8") as out:
            write_jsonl(frames, out)
    speed = stats.duration_s / elapsed if elapsed > 0 else float("inf")
    logger.info(
        "%s: %d records, %.1f s recorded, %d fused frames in %.2f s (%.0f× real time)",
        ", ".join(args.file),
        stats.records,
        stats.duration_s,
        stats.fused_frames,
        elapsed,
        speed,
    )
    if args.export:
        target = _default_target(Path(args.file[0]), args)
        _export(take_from_frames(frames), args, target)
    return 0


def _default_target(source: Path, args: argparse.Namespace) -> Path:
    return Path(args.export_path) if args.export_path else source.with_suffix("." + args.export)


def cmd_export(args: argparse.Namespace) -> int:
    from skelfuse.recording.take import take_from_jsonl

    source = Path(args.file)
    if source.suffix == ".jsonl":
        if args.fusion_config:
            raise CliError(
                f"{source} is fused already: --fusion-config applies to a .sfrec recording"
            )
        take = take_from_jsonl(source)
    else:
        from skelfuse.protocol.recording_file import RecordingError
        from skelfuse.recording.replay import replay
        from skelfuse.recording.take import take_from_frames

        try:
            take = take_from_frames(replay(source, _replay_settings(args)))
        except RecordingError as exc:
            raise CliError(str(exc)) from exc
    _export(take, args, _default_target(source, args))
    return 0


def _export(take: Any, args: argparse.Namespace, target: Path) -> None:
    from skelfuse.recording.take import TakeError

    try:
        if args.export == "bvh":
            from skelfuse.recording.export_bvh import export_bvh

            if args.person is not None and args.person not in take.persons:
                raise CliError(f"no person {args.person}; fused ids: {sorted(take.persons)}")
            track = take.persons[args.person] if args.person is not None else take.main_person()
            result = export_bvh(track, target, fps=args.fps, stretch=args.bvh_stretch)
            logger.info("wrote %s: person %d, %d frames", target, track.person_id, result.frames)
        elif args.export == "csv":
            from skelfuse.recording.export_table import export_csv

            logger.info("wrote %s: %d rows", target, export_csv(take, target))
        elif args.export == "json":
            from skelfuse.recording.export_table import export_json

            export_json(take, target)
            logger.info("wrote %s", target)
        else:
            from skelfuse.recording.export_c3d import export_c3d

            logger.info("wrote %s: %d frames", target, export_c3d(take, target, fps=args.fps))
    except TakeError as exc:
        raise CliError(str(exc)) from exc


def cmd_doctor(args: argparse.Namespace) -> int:
    from skelfuse.agent.sources.registry import check_sources

    bits = 64 if sys.maxsize > 2**32 else 32
    lines = [f"Python {sys.version.split()[0]} ({bits}-bit) on {sys.platform}"]
    for check in check_sources():
        mark = "yes" if check.available else "no "
        lines.append(f"  {check.kind:13s} {mark}  {check.reason}")
    sys.stdout.write("\n".join(lines) + "\n")
    return 0
