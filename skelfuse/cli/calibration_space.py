"""``skelfuse calibration space SPACE --position X Y Z --yaw DEG``: set a tracking space by hand.

Moving sensors (head-mounted cameras) send their poses in a tracking space (their hello's
``pose_space``); the server needs one ``T_world_from_space`` per space (docs/calibration.md
"Tracking spaces"). This stores it, measured by hand: where the space's origin is in the world
(metres) and how far it is turned about the vertical (degrees, a right-handed turn about +Y),
or the whole 4×4 with ``--matrix``; ``--clear`` removes it. Saved as a new version of the
calibration in the server's data folder (atomic; sensors and other spaces kept). A running
server reads it when restarted, or ``POST`` the result of ``GET /api/calibration/export`` to
``/api/calibration/import``: it takes effect at the next fused instant.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from skelfuse.cli.values import UsageError

_SPACE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def add_space_parser(actions: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``calibration space`` and its options under ``skelfuse calibration``."""
    command = actions.add_parser(
        "space",
        help="set (or clear) a tracking space's pose in the world, for moving sensors",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    command.add_argument("space", help="the tracking space id (the agents' --pose-space)")
    how = command.add_mutually_exclusive_group(required=True)
    how.add_argument(
        "--position",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        help="where the space's origin is in the world (metres); with --yaw",
    )
    how.add_argument(
        "--matrix",
        nargs=16,
        type=float,
        metavar="M",
        help="T_world_from_space, 16 numbers row-major (metres)",
    )
    how.add_argument("--clear", action="store_true", help="remove the space's stored pose")
    command.add_argument(
        "--yaw", type=float, default=0.0, help="the space's turn about +Y, degrees (default 0)"
    )
    command.add_argument(
        "--data", default="skelfuse-data", help="the server's data folder (default %(default)s)"
    )
    command.set_defaults(func=run_space)


def run_space(args: argparse.Namespace) -> int:
    """Store (or clear) the space's ``T_world_from_space`` as a new calibration version.

    Raises:
        UsageError: a malformed space id, a matrix that is not a rigid transform, clearing a
            space that is not stored, or an unreadable stored calibration.
    """
    from skelfuse.calibration.errors import CalibrationError
    from skelfuse.calibration.store import CalibrationStore, SpaceCalibration
    from skelfuse.protocol.transform import is_rigid, pose_from_position_yaw_pitch

    if not _SPACE_ID.fullmatch(args.space):
        raise UsageError(f"{args.space!r} is not a space id (1-64 letters, digits, . _ -)")
    store = CalibrationStore(Path(args.data))
    try:
        active = store.load()
    except CalibrationError as exc:
        raise UsageError(str(exc)) from exc
    spaces = dict(active.spaces) if active else {}
    if args.clear:
        if spaces.pop(args.space, None) is None:
            raise UsageError(f"no tracking space {args.space!r} is stored in {store.path}")
        note = f"space {args.space} cleared"
    else:
        if args.matrix is not None:
            matrix = np.array(args.matrix, dtype=np.float64).reshape(4, 4)
        else:
            x, y, z = args.position
            matrix = pose_from_position_yaw_pitch((x, y, z), args.yaw)
        if not is_rigid(matrix, atol=1e-5):
            raise UsageError("--matrix is not a rigid transform (rotation, then 0 0 0 1)")
        spaces[args.space] = SpaceCalibration(matrix, "manual")
        note = f"space {args.space} by hand"
    saved = store.save(dict(active.sensors) if active else {}, note=note, spaces=spaces)
    print(
        f"saved calibration version {saved.version} in {store.path} ({note}); a running server "
        "loads it when restarted (or POST it to /api/calibration/import)"
    )
    return 0
