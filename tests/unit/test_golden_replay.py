"""Golden replay: a recorded take must fuse to what it fused to when it was recorded, within the
feed's rounding.

The take (``tests/data/golden/take.sfrec``: 3 simulated Kinect v2, 2 people, 6 s, made with
``bench.recording.replay.generate_recording(sensors=3, persons=2, duration_s=6.0, seed=11)``)
is a file, not regenerated, so a change to the simulator cannot hide a change to fusion. Each
``fused-<config>.jsonl.gz`` beside it is ``skelfuse replay take.sfrec [--fusion-config
<config>.toml] --out fused.jsonl`` as it was; a deliberate change to fusion writes them again in
the same commit and says why (:func:`write_references`).

The comparison is by tolerance, not by bytes: the same arithmetic may round differently in its
last bit on another CPU or numpy build (SIMD loops, BLAS kernels), and the feed rounds joints
to 0.1 mm and confidences to 0.001, so a last-bit difference can flip one rounding. Everything
but numbers must be equal (frame count, ids, sources, mirrored views, keys); every number may
differ by at most one rounding step of its field, and at most :data:`MAX_CHANGED_SHARE` of them
may differ at all: a real change to fusion moves many values, not a few by one step.
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path
from typing import Any

import pytest

from skelfuse.cli import main

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden"
CONFIGS = {
    # the defaults: body-based confidence, mirror correction, facing, damped-acceleration
    # Kalman, bone-length fit
    "defaults": None,
    # the One Euro filter instead
    "one_euro": "one_euro.toml",
    # Kalman with lead, locked bone estimate, Cauchy re-weighting
    "kalman": "kalman.toml",
    # report A's tracking-state weights alone
    "ablation": "ablation.toml",
}
STEP = {"joints": 1e-4, "confidence": 1e-3, "t": 1e-6}
"""The feed's rounding step per field (docs/api.md): joints 0.1 mm, confidences 0.001; times
are compared to a microsecond."""
MAX_CHANGED_SHARE = 0.01
"""At most this share of the numbers may differ (each by one rounding step at most)."""


def _replay(config: str | None, out: Path) -> list[dict[str, Any]]:
    argv = ["replay", str(GOLDEN / "take.sfrec"), "--out", str(out)]
    if config:
        argv += ["--fusion-config", str(GOLDEN / config)]
    assert main(argv) == 0
    return [json.loads(line) for line in out.read_text(encoding="utf-8").splitlines()]


def _reference(name: str) -> list[dict[str, Any]]:
    with gzip.open(GOLDEN / f"fused-{name}.jsonl.gz", "rt", encoding="utf-8") as stream:
        return [json.loads(line) for line in stream]


class Differences:
    """The numbers compared so far, those that differ, and the first mismatch beyond tolerance."""

    def __init__(self) -> None:
        self.compared = 0
        self.changed = 0
        self.failures: list[str] = []

    def walk(self, got: Any, want: Any, path: str, step: float) -> None:
        """Compare ``got`` with ``want`` (JSON values) under ``path``; numbers within ``step``."""
        if isinstance(want, dict):
            if not isinstance(got, dict) or got.keys() != want.keys():
                self.failures.append(f"{path}: keys {sorted(got)} != {sorted(want)}")
                return
            for key, value in want.items():
                self.walk(got[key], value, f"{path}.{key}", STEP.get(key, step))
        elif isinstance(want, list):
            if not isinstance(got, list) or len(got) != len(want):
                self.failures.append(f"{path}: {got!r} != {want!r}")
                return
            for index, (a, b) in enumerate(zip(got, want, strict=True)):
                self.walk(a, b, f"{path}[{index}]", step)
        elif isinstance(want, float) and not isinstance(got, bool) and step > 0:
            self.compared += 1
            if got != want:
                self.changed += 1
                if not isinstance(got, int | float) or not math.isclose(
                    got, want, rel_tol=0.0, abs_tol=step * 1.000001
                ):
                    self.failures.append(f"{path}: {got!r} != {want!r} (tolerance {step})")
        elif got != want:
            self.failures.append(f"{path}: {got!r} != {want!r}")


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_replay_output_matches_the_golden_output_within_its_rounding(
    name: str, tmp_path: Path
) -> None:
    got = _replay(CONFIGS[name], tmp_path / "fused.jsonl")
    want = _reference(name)
    assert len(got) == len(want) == 181  # the skeleton definition, then 180 fused frames (6 s)
    differences = Differences()
    differences.walk(got, want, "output", step=0.0)
    assert not differences.failures, differences.failures[:10]
    assert differences.compared > 10_000  # the numbers were compared, not skipped
    assert differences.changed <= MAX_CHANGED_SHARE * differences.compared, (
        f"{differences.changed} of {differences.compared} numbers changed by a rounding step"
    )


def test_the_comparison_sees_a_change_beyond_rounding(tmp_path: Path) -> None:
    """A joint moved by 0.2 mm, or a person's id changed, fails the comparison."""
    want = _reference("defaults")
    frame = next(i for i, f in enumerate(want) if f.get("persons"))
    moved = json.loads(json.dumps(want))
    moved[frame]["persons"][0]["joints"][3][1] += 2e-4
    differences = Differences()
    differences.walk(moved, want, "output", step=0.0)
    assert len(differences.failures) == 1 and "joints[3][1]" in differences.failures[0]
    renamed = json.loads(json.dumps(want))
    renamed[frame]["persons"][0]["id"] += 100
    differences = Differences()
    differences.walk(renamed, want, "output", step=0.0)
    assert differences.failures and ".id" in differences.failures[0]


def write_references() -> None:  # pragma: no cover - run by hand after a deliberate change
    """Write ``fused-<config>.jsonl.gz`` again from this tree's replay (``python -c 'from
    tests.unit.test_golden_replay import write_references; write_references()'``)."""
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        for name, config in CONFIGS.items():
            out = Path(folder) / f"{name}.jsonl"
            _replay(config, out)
            with gzip.GzipFile(GOLDEN / f"fused-{name}.jsonl.gz", "wb", mtime=0) as stream:
                stream.write(out.read_bytes())
