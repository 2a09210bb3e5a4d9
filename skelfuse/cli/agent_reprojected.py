"""``skelfuse agent --source azure_kinect|femto --pose-source ... --reproject``: a head-mounted
Azure Kinect / Femto whose body tracker is fed level captures re-projected at each capture's
pose (:class:`~skelfuse.agent.sources.azure_reprojected.ReprojectedAzureKinectSource`).

The source needs the sensor's pose *before* it tracks a capture, so the pose source is not
wrapped around it (as :class:`~skelfuse.agent.poses.posed.PosedSource` does for the others) but
handed to it: :class:`~skelfuse.agent.poses.posed.SensorPoses` (body pose × mount, offset,
counts) is its ``pose_at``.
"""

from __future__ import annotations

import argparse
import time
from typing import Any, cast

from skelfuse.agent.poses.posed import SensorPoses
from skelfuse.agent.sources.base import SensorError, SkeletonSource
from skelfuse.cli.agent_poses import mount_from_args, pose_source_from_args
from skelfuse.cli.values import UsageError


def add_reprojected_options(parser: argparse.ArgumentParser) -> None:
    """``--reproject`` and its reference camera's height."""
    parser.add_argument(
        "--reproject",
        action="store_true",
        help="azure_kinect/femto with --pose-source: track bodies in depth + IR re-projected "
        "into a level camera at each capture's pose (a head-mounted sensor; docs/sensors.md)",
    )
    parser.add_argument(
        "--reference-height-m",
        type=float,
        default=None,
        help="--reproject: the level camera's height in the tracking space (default: the "
        "sensor's own at each capture)",
    )


def reprojected_from_args(args: argparse.Namespace) -> SkeletonSource:
    """The re-projected source ``--reproject`` asks for.

    Raises:
        UsageError: ``--reproject`` with another source or without ``--pose-source``, a bad
            pose option, or a pose source or device that cannot start (its own message).
    """
    from skelfuse.agent.sources.azure_reprojected import ReprojectedAzureKinectSource

    if args.source not in ("azure_kinect", "femto"):
        raise UsageError("--reproject is for --source azure_kinect or femto")
    if args.pose_source is None:
        raise UsageError("--reproject needs --pose-source (the sensor's pose at each capture)")
    try:
        mount = mount_from_args(args)
        poses = SensorPoses(
            pose_source_from_args(args, time.time_ns),  # the source stamps on this PC's clock
            mount=mount,
            offset_ns=round(args.pose_offset_ms * 1e6),
        )
    except (UsageError, SensorError) as exc:
        raise UsageError(f"--pose-source {args.pose_source}: {exc}") from exc
    try:
        source = ReprojectedAzureKinectSource(
            poses.at,
            pose_space=args.pose_space,
            sensor_type=args.source,
            device_index=args.device_index,
            k4a_path=args.k4a_path,
            k4abt_path=args.k4abt_path,
            depth_mode=args.depth_mode,
            reference_height_m=args.reference_height_m,
        )
    except SensorError as exc:
        poses.close()
        raise UsageError(str(exc)) from exc
    return cast(SkeletonSource, _ClosesPoses(source, poses))


class _ClosesPoses:
    """``source`` as it is, whose ``close`` also closes the pose source it was handed."""

    def __init__(self, source: Any, poses: SensorPoses) -> None:
        self._source = source
        self._poses = poses

    def __getattr__(self, name: str) -> Any:
        return getattr(self._source, name)

    def close(self) -> None:
        try:
            self._source.close()
        finally:
            self._poses.close()
