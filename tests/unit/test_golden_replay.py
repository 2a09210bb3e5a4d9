"""Golden replay: a recorded take must fuse to exactly the bytes it fused to when it was recorded.

The take (``tests/data/golden/take.sfrec``: 3 simulated Kinect v2, 2 people, 6 s, made with
``bench.replay.generate_recording(sensors=3, persons=2, duration_s=6.0, seed=11)``) is a file, not
regenerated, so a change to the simulator cannot hide a change to fusion. Each digest is the
SHA-256 of ``skelfuse replay take.sfrec [--fusion-config X] --out fused.jsonl``. A refactor must
keep them; a deliberate change to fusion updates them in the same commit and says why.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from skelfuse.cli import main

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden"

DIGESTS = {
    # defaults: body-based confidence, mirror correction, facing, damped-acceleration Kalman
    # (kalman_ca, the default filter since 2026-11-22), bone-length fit
    "": "222927615841e8325fb64fdd16f55c4026f1711d93dac21ce6af1e6188898ebf",
    # the defaults before that: One Euro (its digest is the old defaults' digest, unchanged)
    "one_euro.toml": "770c0670fdcf9cb457e794488b606c49cf4a656f51c33051b33bd282ae62af70",
    # Kalman with lead, locked bone estimate, Cauchy re-weighting
    "kalman.toml": "25aaab450a15f84708a2847d0755432d848ff4f3b3475f2c316ad3de65ecb9df",
    # report A's tracking-state weights alone
    "ablation.toml": "2d2617a76cf26767a65a14f07a217c86dac7ad95289801c21b29a0eac4d5bc88",
}


@pytest.mark.parametrize("config", sorted(DIGESTS))
def test_replay_output_is_byte_identical_to_the_golden_digest(config: str, tmp_path: Path) -> None:
    out = tmp_path / "fused.jsonl"
    argv = ["replay", str(GOLDEN / "take.sfrec"), "--out", str(out)]
    if config:
        argv += ["--fusion-config", str(GOLDEN / config)]
    assert main(argv) == 0
    lines = out.read_bytes().splitlines()
    assert len(lines) == 181  # the skeleton definition, then 180 fused frames (6 s at 30 Hz)
    assert hashlib.sha256(out.read_bytes()).hexdigest() == DIGESTS[config]
