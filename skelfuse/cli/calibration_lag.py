"""``skelfuse calibration lag SENSOR=SECONDS...``: store sensors' clock lags in the calibration.

A camera whose frames show events later than their stamps (a video's start, an RGB camera's
pipeline) is fused with what the others saw that much earlier once its calibration entry
carries ``lag_s`` (docs/calibration.md §7). The lags come from the motion sync
(``calibration.motion_sync``: ``skelfuse mocap`` logs each camera's, e.g. "cam03: clock +39.2
ms") or a measurement of your own. Saved as a new version of the calibration in the server's
data folder (atomic; the sensors' poses and intrinsics kept). A running server reads it when
restarted, or ``POST`` the result of ``GET /api/calibration/export`` to
``/api/calibration/import``: it takes effect at the next fused instant.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

from skelfuse.cli.values import UsageError

MAX_LAG_S = 10.0
"""Larger lags are refused: a clock that far off is the clock offset's job, not a lag."""


def add_lag_parser(actions: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add ``calibration lag`` and its options under ``skelfuse calibration``."""
    command = actions.add_parser(
        "lag",
        help="store sensors' clock lags (seconds) in the data folder's calibration",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    command.add_argument(
        "lags",
        nargs="+",
        metavar="SENSOR=SECONDS",
        help="how late the sensor's stamps show events, e.g. cam03=0.039 (0 clears it)",
    )
    command.add_argument(
        "--data", default="skelfuse-data", help="the server's data folder (default %(default)s)"
    )
    command.set_defaults(func=run_lag)


def parse_lags(values: list[str]) -> dict[str, float]:
    """``SENSOR=SECONDS`` items → sensor id → lag (seconds).

    Raises:
        UsageError: an item without ``=``, an empty id, a value that is not a finite number or
            beyond :data:`MAX_LAG_S`, or a sensor named twice.
    """
    lags: dict[str, float] = {}
    for value in values:
        sensor, sep, seconds = value.partition("=")
        sensor = sensor.strip()
        try:
            lag = float(seconds)
        except ValueError:
            lag = math.nan
        if not sep or not sensor or not math.isfinite(lag) or abs(lag) > MAX_LAG_S:
            raise UsageError(
                f"{value!r}: expected SENSOR=SECONDS with a number of seconds within "
                f"+-{MAX_LAG_S:g}, e.g. cam03=0.039"
            )
        if sensor in lags:
            raise UsageError(f"sensor {sensor!r} is named twice")
        lags[sensor] = lag
    return lags


def run_lag(args: argparse.Namespace) -> int:
    """Set each named sensor's ``lag_s`` in the active calibration and save it as a new version.

    Raises:
        UsageError: a malformed item, no calibration in the data folder, a sensor it does not
            hold (a lag needs the sensor's pose first: import or calibrate it), or an
            unreadable stored calibration.
    """
    from skelfuse.calibration.errors import CalibrationError
    from skelfuse.calibration.store import CalibrationStore

    lags = parse_lags(args.lags)
    store = CalibrationStore(Path(args.data))
    try:
        active = store.load()
    except CalibrationError as exc:
        raise UsageError(str(exc)) from exc
    known = {} if active is None else active.sensors
    unknown = sorted(set(lags) - set(known))
    if unknown:
        held = ", ".join(sorted(known)) or "none"
        raise UsageError(
            f"no calibrated sensor {', '.join(map(repr, unknown))} in {store.path} (it holds: "
            f"{held}); import or calibrate the sensor first"
        )
    updated = dict(known)
    for sensor, lag in lags.items():
        updated[sensor] = replace(known[sensor], lag_s=lag if lag != 0.0 else None)
        print(f"{sensor}: lag {lag * 1000:+.1f} ms" + ("" if lag else " (cleared)"))
    described = ", ".join(f"{s}={lag:g}" for s, lag in lags.items())
    saved = store.save(updated, note=f"lag {described}")
    print(
        f"saved calibration version {saved.version} in {store.path}; a running server loads it "
        "when restarted (or POST it to /api/calibration/import)"
    )
    return 0
