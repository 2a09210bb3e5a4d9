"""``skelfuse agent --pose-source ...``: make the agent's sensor a moving one (head-mounted).

The sensor's skeleton source is wrapped in :class:`~skelfuse.agent.poses.posed.PosedSource`
with poses from a file or from OpenVR (docs/sensors.md, "Moving sensors"). Without
``--pose-source`` the sensor is fixed and none of these options may be given. Also the
simulator's moving sensors, ``--source sim --scenario mutual`` (``agent/sources/sim_mutual.py``:
their headsets attach the poses themselves).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

from skelfuse.agent.poses.base import PoseSource
from skelfuse.agent.sources.base import SensorError, SkeletonSource
from skelfuse.cli.values import UsageError
from skelfuse.protocol.transform import Matrix4

_SPACE_HINT = (
    "name the tracking space its poses are in, one per tracking system and room (two "
    "headsets with their own tracking are two spaces), e.g. --pose-space openvr-alice"
)


def add_pose_options(parser: argparse.ArgumentParser) -> None:
    """The moving-sensor options of ``skelfuse agent``."""
    parser.add_argument(
        "--pose-source",
        default=None,
        metavar="openvr|file:PATH",
        help="moving sensor: where its poses come from, a SteamVR headset or tracker "
        "(openvr) or a pose file (file:PATH, .csv or .jsonl; see docs/sensors.md)",
    )
    parser.add_argument(
        "--pose-space", default=None, help="moving sensor: the tracking space's id (required)"
    )
    parser.add_argument(
        "--pose-device",
        default=None,
        help="openvr: hmd (default) or a tracked device's serial number, e.g. LHR-1A2B3C4D",
    )
    parser.add_argument(
        "--mount",
        default=None,
        metavar="X,Y,Z,QX,QY,QZ,QW",
        help="moving sensor: the depth camera's pose in the tracked body's frame (metres; "
        "+X the body's left, +Y up, +Z forward; the quaternion turns camera axes into body "
        "axes); default: the camera is the tracked body. Write --mount=-0.1,... when X < 0",
    )
    parser.add_argument(
        "--pose-offset-ms",
        type=float,
        default=0.0,
        help="moving sensor: pose a capture stamped t with the pose at t + this (the pose "
        "clock runs this far ahead of the capture stamps)",
    )
    parser.add_argument(
        "--pose-loop", action="store_true", help="pose file: repeat the track at its end"
    )


# --scenario mutual's options: flag, default (anything else needs --scenario mutual), option.
_MUTUAL = (
    ("--wearer", 0, "wearer"),
    ("--head-axis", "yaw", "head_axis"),
    ("--pose-noise-mm", 0.0, "pose_noise_mm"),
    ("--pose-noise-deg", 0.0, "pose_noise_deg"),
    ("--pose-mismatch-ms", 0.0, "pose_mismatch_ms"),
    ("--walk-m", 0.6, "walk_m"),
    ("--turn-speed", 1.0, "turn_speed"),
)


def add_mutual_options(parser: argparse.ArgumentParser) -> None:
    """``--scenario mutual``: the simulator's head-mounted sensors capturing each other."""
    parser.add_argument(
        "--scenario",
        default=None,
        choices=["mutual"],
        help="sim: 'mutual': wearer --wearer's head-mounted sensor among --persons people who "
        "each wear one (run one agent per wearer; a moving sensor in the space 'room')",
    )
    parser.add_argument("--wearer", type=int, default=0, help="mutual: which person (0-based)")
    parser.add_argument(
        "--head-axis", default="yaw", choices=["yaw", "pitch", "roll"], help="mutual: head turns"
    )
    parser.add_argument(
        "--pose-noise-mm", type=float, default=0.0, help="mutual: headset position noise (σ)"
    )
    parser.add_argument(
        "--pose-noise-deg", type=float, default=0.0, help="mutual: headset rotation noise (σ)"
    )
    parser.add_argument(
        "--pose-mismatch-ms",
        type=float,
        default=0.0,
        help="mutual: the headset attaches the pose of this much later than the capture",
    )
    parser.add_argument(
        "--walk-m", type=float, default=0.6, help="mutual: to-and-fro walk (0: standing)"
    )
    parser.add_argument(
        "--turn-speed", type=float, default=1.0, help="mutual: head schedule rate (1: report B's)"
    )


def mutual_options(args: argparse.Namespace) -> dict[str, object]:
    """The sim source's options of ``--scenario mutual`` (empty without it).

    Raises:
        UsageError: a mutual option without ``--scenario mutual``, or the scenario with another
            source than sim or with ``--pose-source`` (its headsets have their own poses).
    """
    if args.scenario is None:
        given = [flag for flag, default, name in _MUTUAL if getattr(args, name) != default]
        if given:
            raise UsageError(f"{', '.join(given)}: only with --source sim --scenario mutual")
        return {}
    if args.source != "sim":
        raise UsageError("--scenario mutual is a scenario of --source sim")
    if args.pose_source is not None:
        raise UsageError("--scenario mutual's headsets attach their own poses: no --pose-source")
    return {"scenario": "mutual"} | {name: getattr(args, name) for _, _, name in _MUTUAL}


def posed_from_args(args: argparse.Namespace, source: SkeletonSource) -> SkeletonSource:
    """``source`` as a moving sensor when ``--pose-source`` is given, else unchanged.

    Raises:
        UsageError: a pose option without ``--pose-source``, no ``--pose-space``, an unknown
            pose source, a bad ``--mount``, ``--pose-device`` or ``--pose-loop`` with the wrong
            pose source, or a pose source that cannot start (file unreadable or malformed,
            pyopenvr missing, no OpenVR runtime, no such device): its own message. ``source``
            is closed then.
    """
    if args.pose_source is None:
        given = [
            flag
            for flag, value in (
                ("--pose-space", args.pose_space),
                ("--pose-device", args.pose_device),
                ("--mount", args.mount),
                ("--pose-offset-ms", args.pose_offset_ms or None),
                ("--pose-loop", args.pose_loop or None),
            )
            if value is not None
        ]
        if given:
            raise UsageError(f"{', '.join(given)}: only for a moving sensor (--pose-source)")
        return source
    try:
        return _posed(args, source)
    except (UsageError, SensorError) as exc:
        source.close()
        raise UsageError(f"--pose-source {args.pose_source}: {exc}") from exc


def _posed(args: argparse.Namespace, source: SkeletonSource) -> SkeletonSource:
    from skelfuse.agent.poses.posed import PosedSource

    # Poses must be read on the clock the captures are stamped with (a source may have its own).
    clock: Callable[[], int] = getattr(source, "wall_clock_ns", time.time_ns)
    mount = mount_from_args(args)
    return PosedSource(
        source,
        pose_source_from_args(args, clock),
        args.pose_space,
        mount=mount,
        offset_ns=round(args.pose_offset_ms * 1e6),
    )


def mount_from_args(args: argparse.Namespace) -> Matrix4 | None:
    """``--mount`` as ``T_body_from_sensor`` (None without it); checks ``--pose-space`` too.

    Raises:
        UsageError: no ``--pose-space``, ``--mount`` not numbers; SensorError: not a mount.
    """
    from skelfuse.agent.poses.base import mount_matrix

    if not args.pose_space:
        raise UsageError(f"--pose-space is required: {_SPACE_HINT}")
    if args.mount is None:
        return None
    try:
        values = [float(v) for v in args.mount.split(",")]
    except ValueError:
        raise UsageError(f"--mount {args.mount!r}: expected X,Y,Z,QX,QY,QZ,QW") from None
    return mount_matrix(values)


def pose_source_from_args(args: argparse.Namespace, clock: Callable[[], int]) -> PoseSource:
    """The pose source ``--pose-source`` names, read on ``clock`` (the capture stamps').

    Raises:
        UsageError: an unknown pose source, or an option of the other one; SensorError: it
            cannot start (its own message).
    """
    kind, _, path = args.pose_source.partition(":")
    if kind == "file" and path:
        from skelfuse.agent.poses.pose_file import FilePoseSource, read_pose_file

        if args.pose_device is not None:
            raise UsageError("--pose-device is for --pose-source openvr")
        return FilePoseSource(read_pose_file(Path(path)), clock_ns=clock, loop=args.pose_loop)
    if args.pose_source == "openvr":
        from skelfuse.agent.poses.openvr_source import OpenVRPoseSource

        if args.pose_loop:
            raise UsageError("--pose-loop is for a pose file")
        return OpenVRPoseSource(args.pose_device or "hmd", clock_ns=clock)
    raise UsageError("expected openvr or file:PATH")
