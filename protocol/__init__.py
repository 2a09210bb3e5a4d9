"""Shared skeleton model and agent <-> server wire protocol. Depends on numpy and msgpack only
(msgspec, if installed, speeds up decoding frames: ``protocol.wire_canonical``)."""

from skelfuse.protocol.constants import PROTOCOL_VERSION
from skelfuse.protocol.errors import DecodeError, ProtocolError, VersionMismatch
from skelfuse.protocol.skeleton import (
    BONES,
    JOINT_COUNT,
    JOINT_NAMES,
    PARENTS,
    SKELETON_NAME,
    JointId,
    TrackingState,
)

__all__ = [
    "BONES",
    "JOINT_COUNT",
    "JOINT_NAMES",
    "PARENTS",
    "PROTOCOL_VERSION",
    "SKELETON_NAME",
    "DecodeError",
    "JointId",
    "ProtocolError",
    "TrackingState",
    "VersionMismatch",
]
