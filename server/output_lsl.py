"""The Lab Streaming Layer output: fused skeletons as LSL streams (docs/outputs.md, "LSL").

Two streams, pushed with the same timestamp per frame:

- ``skelfuse`` (type ``MoCap``): one sample per fused frame, ``slots`` persons × 25 joints × 4
  channels (x, y, z in metres; confidence 0..1) as float32; a slot without a person, or a joint
  not fused, is NaN (confidence 0). Each channel's label, joint, axis, unit and slot are in the
  stream info's ``<desc><channels>`` (the XDF meta-data's layout).
- ``skelfuse-ids`` (type ``MoCapIds``): per slot, the id of the person in it (-1: empty), int32.

A person keeps the slot it first got while it is fused; a new person takes the lowest free slot;
persons beyond ``slots`` are left out until one frees. Timestamps are on LSL's clock
(``local_clock``): the fused instant (server wall clock) plus LSL's clock minus the wall clock
read together at push time, so a recorder aligns the skeleton with EEG or eye trackers.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, cast

import numpy as np

from skelfuse.fusion.engine import FusedFrame
from skelfuse.protocol.feed import persons_json
from skelfuse.protocol.skeleton import JOINT_COUNT, JOINT_NAMES

CHANNELS_PER_JOINT = 4
_AXES = (("x", "PositionX", "meters"), ("y", "PositionY", "meters"), ("z", "PositionZ", "meters"))


def assign_slots(slots: dict[int, int], ids: list[int], count: int) -> dict[int, int]:
    """Person id → slot for this frame's ``ids``: kept from ``slots``, new ones in the lowest
    free slot, those beyond ``count`` slots left out."""
    kept = {pid: slot for pid, slot in slots.items() if pid in ids}
    free = sorted(set(range(count)) - set(kept.values()))
    for pid in ids:
        if pid not in kept and free:
            kept[pid] = free.pop(0)
    return kept


def frame_sample(
    frame: FusedFrame, slots: dict[int, int], count: int
) -> tuple[list[float], list[int]]:
    """The ``skelfuse`` sample and the ``skelfuse-ids`` sample of one frame (values as the
    feed's: positions to 0.1 mm, confidence to 0.001; ``slots``: :func:`assign_slots`)."""
    sample = np.full((count, JOINT_COUNT, CHANNELS_PER_JOINT), np.nan)
    sample[:, :, 3] = 0.0
    ids = [-1] * count
    for person in persons_json(frame.persons):
        pid = int(person["id"])  # type: ignore[call-overload]
        slot = slots.get(pid)
        if slot is None:
            continue
        ids[slot] = pid
        rows = cast("list[list[float] | None]", person["joints"])
        for j, row in enumerate(rows):
            if row is not None:
                sample[slot, j, :3] = row
        sample[slot, :, 3] = person["confidence"]
    values: list[float] = sample.reshape(-1).tolist()
    return values, ids


def stream_infos(slots: int, rate_hz: float, source_id: str) -> tuple[Any, Any]:
    """The two streams' ``pylsl.StreamInfo``, with channel meta-data.

    Raises:
        ImportError: pylsl is not installed (``pip install 'skelfuse[lsl]'``).
    """
    import pylsl

    info = pylsl.StreamInfo(
        "skelfuse", "MoCap", slots * JOINT_COUNT * CHANNELS_PER_JOINT, rate_hz,
        pylsl.cf_float32, source_id,
    )  # fmt: skip
    desc = info.desc()
    desc.append_child("acquisition").append_child_value("manufacturer", "skelfuse")
    channels = desc.append_child("channels")
    for slot in range(slots):
        for name in JOINT_NAMES:
            for axis, kind, unit in (*_AXES, ("confidence", "Confidence", "normalized")):
                channel = channels.append_child("channel")
                channel.append_child_value("label", f"p{slot}_{name}_{axis}")
                channel.append_child_value("type", kind)
                channel.append_child_value("unit", unit)
                channel.append_child_value("joint", name)
                channel.append_child_value("axis", axis)
                channel.append_child_value("slot", str(slot))
    ids = pylsl.StreamInfo(
        "skelfuse-ids", "MoCapIds", slots, rate_hz, pylsl.cf_int32, f"{source_id}-ids"
    )
    id_channels = ids.desc().append_child("channels")
    for slot in range(slots):
        channel = id_channels.append_child("channel")
        channel.append_child_value("label", f"p{slot}_id")
        channel.append_child_value("slot", str(slot))
    return info, ids


class LslSink:
    """The LSL output's sink: opens both outlets at construction.

    ``wall``: the server's wall clock (Unix seconds, as ``FusedFrame.t_s``); ``lsl_clock``:
    LSL's (None: ``pylsl.local_clock``). Injected so tests drive the mapping.

    Raises:
        ImportError: pylsl is not installed.
    """

    def __init__(
        self,
        slots: int = 6,
        rate_hz: float = 30.0,
        source_id: str = "skelfuse",
        wall: Callable[[], float] = time.time,
        lsl_clock: Callable[[], float] | None = None,
    ) -> None:
        import pylsl

        info, ids = stream_infos(slots, rate_hz, source_id)
        self.outlet = pylsl.StreamOutlet(info)
        self.id_outlet = pylsl.StreamOutlet(ids)
        self.count = slots
        self.slots: dict[int, int] = {}
        self.wall = wall
        self.lsl_clock = lsl_clock or pylsl.local_clock

    def timestamp(self, t_s: float) -> float:
        """The fused instant ``t_s`` (wall clock) on LSL's clock."""
        return t_s + (self.lsl_clock() - self.wall())

    def send(self, frame: FusedFrame) -> int:
        self.slots = assign_slots(self.slots, [p.person_id for p in frame.persons], self.count)
        values, ids = frame_sample(frame, self.slots, self.count)
        stamp = self.timestamp(frame.t_s)
        self.outlet.push_sample(values, stamp)
        self.id_outlet.push_sample(ids, stamp)
        return 0

    def close(self) -> None:
        del self.outlet, self.id_outlet
