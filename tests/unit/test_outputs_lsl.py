"""The LSL output through real liblsl on loopback: an inlet resolves both streams and receives
30 samples equal to the fused frames (the feed's values as float32), ids by slot, timestamps
on LSL's clock mapped from the fused instant, channel meta-data in the stream info."""

from __future__ import annotations

import uuid
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from skelfuse.protocol.feed import persons_json
from skelfuse.protocol.skeleton import JOINT_NAMES
from skelfuse.server.output_lsl import LslSink, assign_slots
from skelfuse.server.outputs import QueuedOutput
from tests.unit.test_outputs_osc import FRAMES, fused_frames

pylsl = pytest.importorskip("pylsl", reason="pylsl is not installed (pip install 'skelfuse[lsl]')")


def test_slots_are_kept_while_a_person_stays_and_reused_once_free() -> None:
    slots = assign_slots({}, [7, 9], 2)
    assert slots == {7: 0, 9: 1}
    slots = assign_slots(slots, [9, 11, 12], 2)  # 7 left: 11 takes its slot, 12 has none
    assert slots == {9: 1, 11: 0}


def test_timestamps_are_the_fused_instant_on_lsl_clock() -> None:
    sink = LslSink(1, 30.0, f"clock-{uuid.uuid4()}", wall=lambda: 1000.5, lsl_clock=lambda: 7.25)
    try:
        assert sink.timestamp(1000.4) == pytest.approx(7.15)  # 0.1 s before the wall's now
    finally:
        sink.close()


def test_an_inlet_receives_30_frames_equal_to_the_fused_ones() -> None:
    source = f"skelfuse-test-{uuid.uuid4()}"
    frames = fused_frames()
    slots = 2
    offset = 123.0  # LSL clock = wall clock + offset, for the test: checks the mapping
    sink = LslSink(slots, 30.0, source, wall=lambda: 0.0, lsl_clock=lambda: offset)
    output = QueuedOutput("lsl", sink, capacity=64)
    (info,) = pylsl.resolve_byprop("source_id", source, 1, 10.0)
    (id_info,) = pylsl.resolve_byprop("source_id", f"{source}-ids", 1, 10.0)
    inlet = pylsl.StreamInlet(info, max_buflen=60)
    ids_inlet = pylsl.StreamInlet(id_info, max_buflen=60)
    full = inlet.info(timeout=10.0)
    inlet.open_stream(timeout=10.0)
    ids_inlet.open_stream(timeout=10.0)
    output.start()
    for frame in frames:
        output.publish(frame, frame.t_s, 0.0)
    samples, stamps = [], []
    id_samples = []
    while len(samples) < FRAMES:
        sample, stamp = inlet.pull_sample(timeout=10.0)
        assert sample is not None, f"{len(samples)} of {FRAMES} samples arrived"
        samples.append(sample)
        stamps.append(stamp)
    while len(id_samples) < FRAMES:
        ids, _ = ids_inlet.pull_sample(timeout=10.0)
        assert ids is not None
        id_samples.append(ids)
    output.close()
    assert (output.sent, output.dropped) == (FRAMES, 0)

    channels = ET.fromstring(full.as_xml()).find("desc/channels")
    assert channels is not None
    first = channels.findall("channel")[:4]
    assert [c.findtext("label") for c in first] == [
        f"p0_{JOINT_NAMES[0]}_{axis}" for axis in ("x", "y", "z", "confidence")
    ]
    assert [c.findtext("unit") for c in first] == ["meters"] * 3 + ["normalized"]
    assert len(channels.findall("channel")) == slots * 25 * 4

    slot_of: dict[int, int] = {}
    for frame, sample, stamp, ids in zip(frames, samples, stamps, id_samples, strict=True):
        assert stamp == pytest.approx(frame.t_s + offset, abs=1e-6)
        slot_of = assign_slots(slot_of, [p.person_id for p in frame.persons], slots)
        values = np.array(sample, dtype=np.float32).reshape(slots, 25, 4)
        for person in persons_json(frame.persons):
            slot = slot_of[int(person["id"])]  # type: ignore[call-overload]
            assert ids[slot] == person["id"]
            for j, row in enumerate(person["joints"]):  # type: ignore[arg-type]
                if row is None:
                    assert np.isnan(values[slot, j, :3]).all()
                else:
                    assert np.array_equal(values[slot, j, :3], np.float32(row))
            assert np.array_equal(values[slot, :, 3], np.float32(person["confidence"]))
        assert sorted(i for i in ids if i >= 0) == sorted(p.person_id for p in frame.persons)
