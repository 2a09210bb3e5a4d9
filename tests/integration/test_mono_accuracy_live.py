"""The leave-one-out pipeline of bench/mono/accuracy.py end to end on the clip's first frames:
two cameras' landmark bodies through the real agent loop to a real server (a subprocess on
loopback), the fused person projected into a third camera and judged there.
Everything it needs is in the repository (tests/data: the landmarks and the calibration).
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.mono.geometry import load_cameras
from bench.mono.live import run_live
from bench.mono.loo import judge, live_limbs
from bench.mono.single import CALIBRATION, Clip, load_clip

FRAMES = 30


@pytest.mark.timeout(180)
def test_two_cameras_fused_live_land_on_the_third_cameras_landmarks() -> None:
    full, cameras = load_clip(), load_cameras(CALIBRATION)
    clip = Clip(
        {c: a[:FRAMES] for c, a in full.image_px.items()},
        {c: a[:FRAMES] for c, a in full.world_m.items()},
        {c: a[:FRAMES] for c, a in full.visibility.items()},
    )
    run = run_live(clip, cameras, ("cam01", "cam02"), {}, hold_s=0.5)

    in_clip = (run.times >= 0) & (run.times <= FRAMES - 1)
    assert in_clip.sum() >= FRAMES // 2 // 2, run.times  # 30 Hz fused over 60 fps frames
    assert (run.persons == 1).all(), run.persons  # one person, never split in two
    assert run.sources == {"cam01+cam02": len(run.times)}, run.sources
    judged = judge(
        live_limbs(run)[in_clip], run.times[in_clip], clip, cameras["cam04"], "cam04", 0.0
    )
    # The live table has 37-43 px for three cameras; a wrong pose, axis or clock gives hundreds.
    assert judged.median_px < 80.0, judged
    assert judged.pck > 0.3, judged
    assert np.isfinite(live_limbs(run)[in_clip]).all()
