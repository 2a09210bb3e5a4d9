"""``skelfuse replay`` and ``skelfuse export``: fuse a recording offline, write motion files.

Replay is deterministic and faster than real time (recording.replay); export writes BVH, CSV,
JSON or C3D from a recording or from fused frames saved as JSON Lines.
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.cli.values import UsageError, fusion_settings, pose_matrix

if TYPE_CHECKING:
    from skelfuse.protocol.transform import Matrix4
    from skelfuse.recording.take import Take
    from skelfuse.server.settings import Settings

logger = logging.getLogger("skelfuse")
EXPORT_FORMATS = ("bvh", "csv", "json", "c3d")


def add_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``replay`` and ``export`` to the command line."""
    replay = sub.add_parser(
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
    replay.set_defaults(func=run_replay)

    export = sub.add_parser(
        "export", help="export fused motion (from a recording or a fused .jsonl) to a file"
    )
    export.add_argument("file", help="a .sfrec recording or fused frames as .jsonl")
    _fusion_config_option(export)
    _export_options(export, required=True)
    export.set_defaults(func=run_export)


def _fusion_config_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--fusion-config",
        default=None,
        metavar="FILE",
        help="a recording: fuse it with this TOML [fusion] table's settings (docs/fusion.md §9)",
    )


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


def run_replay(args: argparse.Namespace) -> int:
    """Fuse the recording, log the speed-up, optionally write JSON Lines and an export; 0.

    Raises:
        UsageError: an unreadable recording, a bad ``--pose`` / ``--fusion-config``, or an
            export that cannot be written from this take.
    """
    from skelfuse.protocol.recording_file import RecordingError
    from skelfuse.recording.replay import ReplayStats, replay, write_jsonl
    from skelfuse.recording.take import take_from_frames

    path, tmp = _recording_path(args)
    stats = ReplayStats()
    started = time.perf_counter()
    try:
        frames = list(replay(path, _replay_settings(args), stats=stats))
    except RecordingError as exc:
        raise UsageError(str(exc)) from exc
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


def run_export(args: argparse.Namespace) -> int:
    """Export a recording (fused first) or fused ``.jsonl`` frames; 0.

    Raises:
        UsageError: an unreadable input, ``--fusion-config`` with frames fused already, or an
            export that cannot be written from this take.
    """
    from skelfuse.recording.take import take_from_jsonl

    source = Path(args.file)
    if source.suffix == ".jsonl":
        if args.fusion_config:
            raise UsageError(
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
            raise UsageError(str(exc)) from exc
    _export(take, args, _default_target(source, args))
    return 0


def _recording_path(
    args: argparse.Namespace,
) -> tuple[Path, tempfile.TemporaryDirectory[str] | None]:
    """The .sfrec to replay: the file given, or one made from NTU files (in a temporary folder
    the caller cleans up)."""
    files = [Path(f) for f in args.file] if isinstance(args.file, list) else [Path(args.file)]
    if all(f.suffix == ".skeleton" for f in files):
        from skelfuse.protocol.ntu import NtuFormatError
        from skelfuse.protocol.recording_file import write_recording
        from skelfuse.recording.ntu_import import ntu_recording

        poses = args.pose or []
        if poses and len(poses) != len(files):
            raise UsageError(f"give one --pose per NTU file ({len(files)}), or none")
        matrices: list[Matrix4 | None] = [pose_matrix(p) for p in poses] or [None] * len(files)
        if not poses:
            logger.warning(
                "NTU files carry no camera poses: without --pose nothing is fused "
                "(skeleton calibration is a later issue)"
            )
        try:
            header, records = ntu_recording(files, matrices)
        except NtuFormatError as exc:
            raise UsageError(str(exc)) from exc
        tmp = tempfile.TemporaryDirectory(prefix="skelfuse-ntu-")
        path = Path(tmp.name) / "ntu.sfrec"
        write_recording(path, header, records)
        return path, tmp
    if len(files) != 1:
        raise UsageError("give one recording (several files only for NTU .skeleton)")
    return files[0], None


def _replay_settings(args: argparse.Namespace) -> Settings:
    """Server settings for an offline replay: defaults, or ``--fusion-config``."""
    from skelfuse.server.settings import Settings

    return Settings(fusion=fusion_settings(args.fusion_config))  # UsageError on a bad file


def _default_target(source: Path, args: argparse.Namespace) -> Path:
    return Path(args.export_path) if args.export_path else source.with_suffix("." + args.export)


def _export(take: Take, args: argparse.Namespace, target: Path) -> None:
    from skelfuse.recording.take import TakeError

    try:
        if args.export == "bvh":
            from skelfuse.recording.export_bvh import export_bvh

            if args.person is not None and args.person not in take.persons:
                raise UsageError(f"no person {args.person}; fused ids: {sorted(take.persons)}")
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
        raise UsageError(str(exc)) from exc
