"""Whether a calibration run can start now (:func:`validate`): the method, the sensors known and
connected, and what each method needs (docs/calibration.md, "REST API": refusals)."""

from __future__ import annotations

from skelfuse.server.calibration_run import RunSpec
from skelfuse.server.errors import Conflict, InvalidRequest, SensorUnavailable
from skelfuse.server.hub import FusionHub

METHODS = ("auto", "skeleton", "points", "icp", "sensor")


def validate(spec: RunSpec, hub: FusionHub) -> None:
    """Refuse a run that cannot start now.

    Raises:
        Conflict: a sensor is offline or has no starting pose, or too few sensors are
            connected for the method.
        SensorUnavailable: a sensor (or the reference) is unknown: never connected.
        InvalidRequest: an unknown method, no points, or no single sensor for method sensor.
    """
    if spec.method not in METHODS:
        raise InvalidRequest(f"method must be one of {', '.join(METHODS)}")
    known = hub.sensors
    unknown = [s for s in spec.sensors if s not in known]
    if spec.reference != "world" and spec.reference not in known:
        unknown.append(spec.reference)
    if unknown:  # not connected yet, as far as the server can tell: 409, retry later
        raise SensorUnavailable(
            f"unknown sensor(s) {sorted(set(unknown))}: no agent with that id has connected; "
            f"known: {sorted(known) or 'none'}"
        )
    if spec.method == "points":
        if not spec.points:
            raise InvalidRequest("method points needs 'points': at least 3 pairs per sensor")
        return
    offline = [s for s in spec.sensors if not known[s].connected]
    if offline:
        raise Conflict(f"sensor(s) {offline} are offline; start their agents and retry")
    if spec.method == "sensor":
        if len(spec.sensors) != 1:
            raise InvalidRequest("method sensor re-solves one sensor: name it in 'sensor'")
        if set(hub.connected_poses()) <= {spec.sensors[0]}:
            raise Conflict(
                "method sensor solves a sensor against the others: it needs at least one "
                "other connected sensor with a pose"
            )
        return
    if len(spec.sensors) < 2 and spec.method in ("skeleton", "auto"):
        raise Conflict(f"method {spec.method} needs at least 2 connected sensors")
    if spec.reference not in spec.sensors:
        raise InvalidRequest("the reference must be one of the run's sensors")
    if spec.method == "icp":
        missing = [s for s in spec.sensors if hub.pose_of(s)[0] is None]
        if missing:
            raise Conflict(
                f"icp refines existing poses, but {missing} have none: run 'skeleton', "
                "'points' or 'auto' first"
            )
