"""The live feed's JSON (orjson, server/broadcast.py) is the text ``json.dumps`` wrote before.

Real fused frames from the golden take (tests/data/golden/take.sfrec), with and without the raw
bodies, must encode to exactly the compact ``json.dumps`` text: apps see the same bytes as before
the switch, and offline replay (which keeps ``json``) stays comparable to the live feed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bench.live.encode import sample_frame
from skelfuse.protocol.feed import frame_json, person_json, persons_json, round_like_python
from skelfuse.protocol.skeleton import skeleton_definition
from skelfuse.recording.replay import replay
from skelfuse.server.broadcast import encode_message

TAKE = Path(__file__).resolve().parents[1] / "data" / "golden" / "take.sfrec"


def _json_dumps(message: dict[str, object]) -> str:
    return json.dumps(message, allow_nan=False, separators=(",", ":"))


def test_live_json_matches_json_dumps_byte_for_byte_on_real_frames() -> None:
    frames = list(replay(TAKE))
    assert len(frames) == 180 and any(frame.persons for frame in frames)
    for k, frame in enumerate(frames):
        for include_raw in (False, True):
            message = frame_json(frame, include_raw, 1_763_712_345.123456 + k / 30)
            assert encode_message(message, binary=False) == _json_dumps(message)
    greeting = skeleton_definition()
    assert encode_message(greeting, binary=False) == _json_dumps(greeting)


def test_numpy_scalars_are_written_as_numbers() -> None:
    message = {"t": np.float64(1.5), "n": np.int64(3), "c": [np.float32(0.25)]}
    assert encode_message(message, binary=False) == '{"t":1.5,"n":3,"c":[0.25]}'


def test_vectorised_rounding_gives_what_python_round_gives() -> None:
    rng = np.random.default_rng(7)
    # near-halves (0.0025 is 0.00250000000000000005...: Python rounds it up, rint(2.5) down),
    # exact thousandths, and random values, as confidences are
    halves = (np.arange(0, 1000) + 0.5) / 1000
    values = np.concatenate([halves, np.arange(0, 1001) / 1000, rng.random(20_000)])
    expected = [round(float(v), 3) for v in values]
    assert round_like_python(values, 3).tolist() == expected
    assert round_like_python(np.array([0.0025]), 3).tolist() == [0.003]


def test_a_person_s_unknown_joint_is_null_with_confidence_zero() -> None:
    person = sample_frame(1).persons[0]
    (sent,) = persons_json([person])
    assert sent["joints"][15] is None and sent["confidence"][15] == 0.0  # type: ignore[index]
    assert sent == person_json(person)
