"""``skelfuse agent``: one capture agent for one sensor, sending to the server over ZeroMQ.

Only numpy, pyzmq and msgpack are needed here (a sensor PC installs no server extras); sensor
SDKs are imported by their sources when chosen.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Any

from skelfuse.agent.sources.base import SensorError, SkeletonSource
from skelfuse.agent.sources.registry import SOURCE_KINDS
from skelfuse.cli.agent_poses import (
    add_mutual_options,
    add_pose_options,
    mutual_options,
    posed_from_args,
)
from skelfuse.cli.agent_reprojected import add_reprojected_options, reprojected_from_args
from skelfuse.cli.values import UsageError, pose_matrix
from skelfuse.protocol.constants import DEFAULT_ZMQ_PORT

SIM_DEFAULT_POSE = "0,1.0,3.0,180"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``agent`` with the options of every source kind to the command line."""
    agent = sub.add_parser("agent", help="run a capture agent for one sensor")
    agent.add_argument(
        "--source",
        default="sim",
        choices=list(SOURCE_KINDS),
        help="sensor source; 'skelfuse doctor' says which can run on this PC",
    )
    agent.add_argument(
        "--server",
        default=f"tcp://127.0.0.1:{DEFAULT_ZMQ_PORT}",
        help="the server's ZeroMQ endpoint, tcp://HOST:PORT (default %(default)s)",
    )
    agent.add_argument("--id", required=True, help="this sensor's unique id, e.g. kinect-front")
    agent.add_argument(
        "--pose",
        default=None,
        help=f"X,Y,Z,YAW_DEG[,PITCH_DEG]: sim: where the simulated sensor stands (default "
        f"{SIM_DEFAULT_POSE}); real sensors: a hand-measured pose sent as a hint until "
        "calibrated (metres, Y up; yaw 0 looks along +Z, 90 along +X; +pitch looks down); "
        "write --pose=-2,1,3,90 when X is negative",
    )
    agent.add_argument("--persons", type=int, default=2, help="sim: people in the room (1-6)")
    agent.add_argument("--seed", type=int, default=None, help="sim: noise seed (default: from id)")
    agent.add_argument(
        "--clock-offset-ms",
        type=float,
        default=0.0,
        help="sim: pretend this PC's clock is off by this much",
    )
    agent.add_argument(
        "--clock-drift-ppm",
        type=float,
        default=0.0,
        help="sim: pretend this PC's clock runs fast (or slow, if negative) by this much",
    )
    agent.add_argument(
        "--no-pose-hint",
        dest="pose_hint",
        action="store_false",
        help="sim: do not tell the server the true pose (calibrate instead)",
    )
    agent.add_argument(
        "--error-model",
        choices=("kinect", "tracker"),
        default="kinect",
        help="sim: the sensor's error model: the Kinect v2 model or the depth body tracker "
        "(docs/simulator.md)",
    )
    agent.add_argument(
        "--random-sensor",
        action="store_true",
        help="sim: a sensor unit with parameters drawn from the seed (docs/simulator.md)",
    )
    agent.add_argument("--key", default=None, help="CurveZMQ: this agent's <id>.key_secret file")
    agent.add_argument(
        "--server-key", default=None, help="CurveZMQ: the server's public key file (server.key)"
    )
    agent.add_argument("--duration", type=float, default=None, help="stop after N seconds")
    agent.set_defaults(func=run)
    _add_source_options(agent)
    add_pose_options(agent)
    add_mutual_options(agent)
    add_reprojected_options(agent)


def _add_source_options(parser: argparse.ArgumentParser) -> None:
    """Options of the non-sim sources (``--source`` itself is defined with the agent's)."""
    parser.add_argument("--file", default=None, help="replay: a .sfrec recording; ntu: a .skeleton")
    parser.add_argument("--sensor", default=None, help="replay: which recorded sensor to play")
    parser.add_argument(
        "--loop", action="store_true", help="replay/ntu/mono --video: start again at the end"
    )
    parser.add_argument(
        "--speed", type=float, default=1.0, help="replay/mono --video: playback speed factor"
    )
    parser.add_argument(
        "--start-at",
        type=float,
        default=None,
        help="ntu, mono --video: Unix time of frame 0 (the same value for the cameras of a take)",
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
    parser.add_argument("--camera", type=int, default=None, help="mono: webcam index (0, 1, ...)")
    parser.add_argument("--video", default=None, help="mono: a video file, played at its pace")
    parser.add_argument(
        "--intrinsics",
        default=None,
        help="mono: the camera's fx,fy,cx,cy in pixels (without it: a guess from --fov)",
    )
    parser.add_argument(
        "--calibration",
        default=None,
        help="mono: a camera calibration file (Qualisys .qca.txt, Pose2Sim .toml, OpenCV "
        ".yml/.xml): the camera's intrinsics and lens distortion, its pose as the pose hint",
    )
    parser.add_argument(
        "--calibration-format",
        default=None,
        choices=["qualisys", "pose2sim", "opencv"],
        help="mono: the --calibration file's format (default: from its extension)",
    )
    parser.add_argument(
        "--calibration-camera",
        default=None,
        help="mono: which camera of --calibration (default: its only one)",
    )
    parser.add_argument(
        "--fov",
        type=float,
        default=None,
        help="mono: horizontal field of view in degrees for a guessed focal length (default 60; "
        "distances scale with it, so prefer --intrinsics)",
    )


def run(args: argparse.Namespace) -> int:
    """Send frames until SIGINT/SIGTERM or ``--duration``; 0.

    Raises:
        UsageError: a bad ``--pose``, ``--persons``, source or pose source option, or half a
            CurveZMQ pair.
    """
    from skelfuse.agent.runner import run_agent

    source = sensor_from_args(args)
    curve = None
    if args.key or args.server_key:
        if not (args.key and args.server_key):
            raise UsageError(
                "CurveZMQ needs both --key (this agent's .key_secret) and --server-key"
            )
        from skelfuse.agent.link import CurveKeys

        curve = CurveKeys(Path(args.key), Path(args.server_key))
    stop = _stop_on_signals()
    started = time.monotonic()
    try:
        link = run_agent(
            args.id, source, args.server, stop=stop, duration_s=args.duration, curve=curve
        )
    except SensorError as exc:  # a camera that stops, a calibration that does not fit its frames
        raise UsageError(f"{args.id}: {exc}") from exc
    logging.getLogger("skelfuse.agent").info(
        "%s stopped after %.0f s: %d frames sent, %d dropped",
        args.id,
        time.monotonic() - started,
        link.stats.frames_sent,
        link.stats.frames_dropped,
    )
    unposed = getattr(source, "unposed", None)  # a moving sensor's (agent/poses/posed.py)
    if unposed:
        logging.getLogger("skelfuse.agent").info(
            "%s: %d captures not sent for want of a pose (%s)",
            args.id,
            sum(unposed.values()),
            ", ".join(f"{n} {why}" for why, n in unposed.most_common()),
        )
    return 0


def sensor_from_args(args: argparse.Namespace) -> SkeletonSource:
    """The source with its poses when it moves: ``--reproject`` (a head-mounted Azure Kinect /
    Femto), ``--pose-source`` around any source, or :func:`source_from_args` alone.

    Raises:
        UsageError: as :func:`source_from_args` and the pose options' own checks.
    """
    if args.reproject:
        mutual_options(args)  # only its checks: the scenario is the simulator's
        return reprojected_from_args(args)
    if args.reference_height_m is not None:
        raise UsageError("--reference-height-m is for --reproject")
    return posed_from_args(args, source_from_args(args))


def source_from_args(args: argparse.Namespace) -> SkeletonSource:
    """The source ``skelfuse agent --source KIND ...`` asks for.

    ``sim`` uses ``--pose`` (default :data:`SIM_DEFAULT_POSE`), ``--persons``, ``--seed``,
    ``--clock-offset-ms``, ``--clock-drift-ppm``, ``--error-model``, ``--random-sensor``
    (with ``--scenario mutual``: ``--wearer`` and the options of
    :func:`~skelfuse.cli.agent_poses.mutual_options`); for the real sensors and ``ntu``,
    ``--pose`` is announced as a manual pose hint only when given, since a real
    sensor's pose is not known.

    Raises:
        UsageError: an unknown kind, a bad ``--pose`` or ``--persons``, or a source that cannot
            start (the SDK is missing, the file does not exist: the source's own message).
    """
    from skelfuse.agent.sources.registry import make_source

    kind = args.source
    if kind not in SOURCE_KINDS:
        raise UsageError(f"unknown source {kind!r}: choose one of {', '.join(SOURCE_KINDS)}")
    options: dict[str, Any] = {
        "file": args.file,
        "sensor": args.sensor,
        "loop": args.loop,
        "speed": args.speed,
        "start_unix_s": args.start_at,
        "device_index": args.device_index,
        "k4a_path": args.k4a_path,
        "k4abt_path": args.k4abt_path,
        "depth_mode": args.depth_mode,
        "camera": args.camera,
        "video": args.video,
        "intrinsics": args.intrinsics,
        "fov_deg": args.fov,
        "pose": pose_matrix(args.pose) if args.pose is not None else None,
    }
    if kind == "mono" and args.calibration:
        from skelfuse.cli.agent_lens import calibrated_lens

        if args.intrinsics:
            raise UsageError("give --intrinsics or --calibration, not both")
        lens, pose = calibrated_lens(
            Path(args.calibration), args.calibration_format, args.calibration_camera
        )
        options["lens"] = lens
        if options["pose"] is None:
            options["pose"] = pose
    if kind == "sim":
        if not 1 <= args.persons <= 6:
            raise UsageError("--persons must be 1..6")
        options.update(
            pose=pose_matrix(args.pose or SIM_DEFAULT_POSE),
            persons=args.persons,
            seed=args.seed if args.seed is not None else sum(args.id.encode()),
            clock_offset_ns=int(args.clock_offset_ms * 1e6),
            clock_drift_ppm=float(args.clock_drift_ppm),
            send_pose_hint=args.pose_hint,
            error_model=args.error_model,
            random_sensor=args.random_sensor,
        )
    options.update(mutual_options(args))  # --scenario mutual: a head-mounted sim sensor
    try:
        return make_source(kind, options)
    except SensorError as exc:
        raise UsageError(str(exc)) from exc


def _stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM (the agent's loop checks it between frames)."""
    stop = threading.Event()

    def handler(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop
