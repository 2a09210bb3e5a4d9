"""The ``mono`` source with the real model on the real clip: MediaPipe Pose in ``.venv-mono``
(``scripts/venv_mono.sh``; mediapipe 0.10.21 pins numpy<2, so not in this environment), streamed
by the real agent loop to a real server. Every Python socket connect and name lookup in the
agent's process is refused and counted: the model loads from the wheel, nothing downloads.

Skips with a visible reason without ``.venv-mono`` or the clip (``../shared/data``), and fails
under CI, which makes both. CPU per frame is a figure for bench/mono/source.py, not asserted.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skelfuse.geometry.pinhole import Intrinsics
from skelfuse.protocol.mediapipe_pose import body_from_landmarks
from tests.integration.conftest import LiveServer
from tests.support import unavailable, wait_until

ROOT = Path(__file__).resolve().parents[2]
MONO_PYTHON = ROOT / ".venv-mono" / "bin" / "python"
CLIP = ROOT.parent / "shared" / "data" / "pose2sim-single" / "cam01.mp4"
CHILD = Path(__file__).with_name("mono_agent_child.py")
FIXTURE = ROOT / "tests" / "data" / "mono_landmarks.npz"
CLIP_FRAMES = 100


def _sensor(live: LiveServer, sensor_id: str) -> dict[str, Any] | None:
    import httpx

    rows = httpx.get(f"{live.http_url}/api/sensors", timeout=5).json()["sensors"]
    return next((row for row in rows if row["id"] == sensor_id), None)


@pytest.mark.timeout(300)
def test_mono_source_streams_every_frame_of_the_real_clip_without_network(
    server_factory: Any, tmp_path: Path
) -> None:
    if not MONO_PYTHON.is_file():
        unavailable(
            f"no mono environment at {MONO_PYTHON}: make it with scripts/venv_mono.sh",
            "scripts/test.sh makes it (scripts/venv_mono.sh)",
        )
    if not CLIP.is_file():
        unavailable(f"the real clip is not at {CLIP}", "CI must provide ../shared/data")
    doctor = subprocess.run(
        [str(MONO_PYTHON), "-m", "skelfuse", "doctor"],
        cwd=ROOT, capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    assert re.search(r"^\s*mono\s+yes\s+mediapipe 0\.10\.21", doctor.stdout, re.M), doctor.stdout
    live = server_factory()
    sent_path = tmp_path / "sent.npz"
    done = subprocess.run(
        [str(MONO_PYTHON), str(CHILD), str(CLIP), live.zmq_url, "cam01-mono", str(sent_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=240, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["network_attempts"] == []
    assert report["finished"] and report["frames_read"] == CLIP_FRAMES
    assert report["frames_with_body"] == CLIP_FRAMES  # detection on 100 % of frames
    assert report["frames_sent"] == CLIP_FRAMES and report["frames_dropped"] == 0
    # The server took them all, from an rgb sensor, none rejected.
    assert wait_until(
        lambda: (_sensor(live, "cam01-mono") or {}).get("frames_received") == CLIP_FRAMES, 10.0
    ), json.dumps(_sensor(live, "cam01-mono"))
    row = _sensor(live, "cam01-mono")
    assert row is not None and row["type"] == "rgb" and not row["frames_rejected"], row
    # The live model saw what the stored landmarks say (tests/data/mono_landmarks.npz, which the
    # unit tests use): the same bodies through the same mapping (bit for bit on the machine
    # that made the file; within 2 mm and 1 % of states where another CPU's kernels round
    # differently).
    with np.load(sent_path) as sent, np.load(FIXTURE) as stored:
        width, height = (int(v) for v in stored["cam01_size_wh"])
        k = Intrinsics.from_fov(width, height, 50.0)
        previous, same_states = None, []
        for f in range(CLIP_FRAMES):
            body = body_from_landmarks(
                stored["cam01_image_px"][f], stored["cam01_world_m"][f],
                stored["cam01_visibility"][f], (width, height), k, initial=previous,
            )  # fmt: skip
            previous = body.placement
            np.testing.assert_allclose(sent["joints_m"][f], body.joints_m, atol=0.002)
            same_states.append(sent["states"][f] == body.states)
    assert np.mean(same_states) >= 0.99
