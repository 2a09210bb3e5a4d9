"""``skelfuse calibration import FILE``: RGB cameras' calibration files into the project's.

Reads a Qualisys ``.qca.txt``, a Pose2Sim ``.toml`` or an OpenCV FileStorage file
(``calibration/camera_files.py``), turns it into each camera's ``T_world_from_sensor`` (metres,
+Y up) and intrinsics, and saves it as a new version of the calibration in the server's data
folder (``calibration/store.py``: atomic, sensors not in the file keep their poses). A running
server reads the calibration at start-up: restart it, or ``POST`` the result of
``GET /api/calibration/export`` to ``/api/calibration/import``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from skelfuse.cli.calibration_lag import add_lag_parser
from skelfuse.cli.calibration_space import add_space_parser
from skelfuse.cli.values import UsageError

if TYPE_CHECKING:
    from skelfuse.calibration.store import SensorCalibration


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``calibration import`` (and ``calibration lag``, ``calibration space``) and their
    options to the command line."""
    calibration = sub.add_parser(
        "calibration", help="import camera calibration files, store sensors' clock lags"
    )
    actions = calibration.add_subparsers(dest="calibration_command", required=True)
    command = actions.add_parser(
        "import",
        help="import a Qualisys, Pose2Sim or OpenCV calibration file into the data folder",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    command.add_argument("file", help="the calibration file")
    command.add_argument(
        "--format",
        required=True,
        choices=("qualisys", "pose2sim", "opencv"),
        help="qualisys (.qca.txt), pose2sim (.toml) or opencv (FileStorage .yml/.yaml/.xml)",
    )
    command.add_argument(
        "--up",
        choices=("y", "z"),
        default=None,
        help="the file's world up axis (default z for qualisys and pose2sim, y for opencv)",
    )
    command.add_argument(
        "--data",
        default="skelfuse-data",
        help="the server's data folder (default %(default)s)",
    )
    command.add_argument(
        "--sensor",
        action="append",
        default=[],
        metavar="CAMERA=SENSOR_ID",
        help="store camera CAMERA under the agent's sensor id SENSOR_ID (repeatable)",
    )
    command.add_argument(
        "--dry-run", action="store_true", help="read and show the cameras, save nothing"
    )
    command.set_defaults(func=run_import)
    add_lag_parser(actions)
    add_space_parser(actions)


def run_import(args: argparse.Namespace) -> int:
    """Read, convert, show and save; a malformed file is a usage error naming the field.

    Raises:
        UsageError: the file cannot be read or is malformed, or a ``--sensor`` is malformed
            or names no camera of the file.
    """
    from skelfuse.calibration.camera_files import as_sensor_calibrations, read_camera_file
    from skelfuse.calibration.errors import CalibrationError
    from skelfuse.calibration.store import CalibrationStore, merge

    rename = _renames(args.sensor)
    path = Path(args.file)
    try:
        found = read_camera_file(path, args.format, up=args.up)
        sensors = as_sensor_calibrations(found, args.format, rename=rename)
    except CalibrationError as exc:
        raise UsageError(str(exc)) from exc
    for warning in found.warnings:
        print(f"warning: {warning}")
    for sensor_id, entry in sensors.items():
        print(_describe(sensor_id, entry))
    if args.dry_run:
        return 0
    store = CalibrationStore(Path(args.data))
    try:
        saved = store.save(merge(store.load(), sensors), note=f"imported {path.name}")
    except CalibrationError as exc:  # the stored calibration itself is unreadable
        raise UsageError(str(exc)) from exc
    print(
        f"saved calibration version {saved.version} in {store.path} "
        f"({len(sensors)} camera(s) from {path.name}); a running server loads it when restarted"
    )
    return 0


def _renames(values: list[str]) -> dict[str, str]:
    renames: dict[str, str] = {}
    for value in values:
        camera, sep, sensor = value.partition("=")
        if not sep or not camera.strip() or not sensor.strip():
            raise UsageError(f"--sensor {value!r}: expected CAMERA=SENSOR_ID")
        renames[camera.strip()] = sensor.strip()
    return renames


def _describe(sensor_id: str, entry: SensorCalibration) -> str:
    position = entry.T_world_from_sensor[:3, 3]
    k = entry.intrinsics
    lens = "" if k is None else f", {k.width}x{k.height} px, f {k.fx:.1f}/{k.fy:.1f} px"
    return f"{sensor_id}: at x {position[0]:.3f}, y {position[1]:.3f}, z {position[2]:.3f} m{lens}"
