"""``skelfuse mocap``: videos (or their stored landmarks) → a BVH and a C3D that independent
tools read: bvhio and ezc3d always, Debian's Blender headless (every frame imported).

Most tests run on ``tests/data/mono_landmarks.npz`` (``--landmarks``: no model). The end-to-end
tests detect on the real clip in the mono environment (``scripts/venv_mono.sh`` makes
``.venv-mono``): they skip with a visible reason without it, and fail under CI, as a missing
Blender does.
"""

from __future__ import annotations

import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.camera_files import read_camera_file
from skelfuse.calibration.triangulation import triangulate
from skelfuse.cli import main
from skelfuse.cli.mocap_stages import mono_python
from skelfuse.geometry.pinhole import CV_TO_SENSOR
from skelfuse.protocol.mediapipe_pose import to_kinect_v2
from skelfuse.protocol.skeleton import JOINT_NAMES
from tests.support import require_blender, unavailable
from tests.support_blender import blender_bvh_positions
from tests.support_exports import bvhio_positions_m, ezc3d_world_m

with warnings.catch_warnings():
    # bvhio (dev extra) imports PyGLM as "glm", which warns about that name on first import.
    warnings.simplefilter("ignore", PendingDeprecationWarning)
    import bvhio  # noqa: F401

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
LANDMARKS = DATA / "mono_landmarks.npz"
CALIBRATION = DATA / "pose2sim_single_calib.qca.txt"
CLIP = ROOT.parent / "shared" / "data" / "pose2sim-single"
CAMERAS = ("cam01", "cam02", "cam03", "cam04")


def _videos(names: tuple[str, ...] = CAMERAS) -> list[str]:
    return [f"{name}.mp4" for name in names]  # with --landmarks only their names are used


@dataclass(frozen=True)
class Take:
    bvh: Path
    c3d: Path
    frames: int


def _mocap(out: Path, *args: str) -> Take:
    assert main(["mocap", *args, "-o", str(out)]) == 0
    positions = bvhio_positions_m(out, list(JOINT_NAMES))
    return Take(out, out.with_suffix(".c3d"), positions.shape[0])


@pytest.fixture(scope="module")
def four(tmp_path_factory: pytest.TempPathFactory) -> Take:
    out = tmp_path_factory.mktemp("mocap4") / "take.bvh"
    return _mocap(out, *_videos(), "--calibration", str(CALIBRATION), "--landmarks",
                  str(LANDMARKS), "--video-fps", "60", "--bvh-stretch")  # fmt: skip


@pytest.fixture(scope="module")
def single(tmp_path_factory: pytest.TempPathFactory) -> Take:
    out = tmp_path_factory.mktemp("mocap1") / "one.bvh"
    return _mocap(out, *_videos(("cam02",)), "--landmarks", str(LANDMARKS), "--fov", "36",
                  "--video-fps", "60")  # fmt: skip


def _reference() -> np.ndarray:
    """The 25 joints triangulated from all four views (cam03's 2-frame lag removed), world."""
    cameras = {c.name: c for c in read_camera_file(CALIBRATION, "qualisys").cameras}
    with np.load(LANDMARKS) as data:
        px = np.stack([data[f"{n}_image_px"][..., :2] for n in CAMERAS]).astype(np.float64)
        weights = np.stack([data[f"{n}_visibility"] for n in CAMERAS]).astype(np.float64)
    px[2, :-2], px[2, -2:] = px[2, 2:], np.nan
    weights[2, :-2], weights[2, -2:] = weights[2, 2:], 0.0
    points = triangulate([cameras[n] for n in CAMERAS], px, weights, max_error_px=20).points_world
    every = np.full(33, 2, dtype=np.uint8)
    return np.stack([to_kinect_v2(p, every)[0] * CV_TO_SENSOR for p in points])


def test_four_videos_give_a_bvh_and_a_c3d_of_the_same_motion(four: Take) -> None:
    assert four.frames >= 95  # 100 video frames at 60 fps, fused on a 60 Hz grid
    bvh = bvhio_positions_m(four.bvh, list(JOINT_NAMES))
    c3d = ezc3d_world_m(four.c3d, [f"P1_{n}" for n in JOINT_NAMES])
    assert c3d.shape == bvh.shape
    np.testing.assert_allclose(bvh, c3d, atol=1e-4)  # stretch BVH: exact joints


def test_the_fused_take_follows_the_four_view_reference(four: Take) -> None:
    bvh = bvhio_positions_m(four.bvh, list(JOINT_NAMES))
    reference = _reference()[: bvh.shape[0]]
    errors = np.linalg.norm(bvh - reference, axis=-1) * 1000.0
    # Measured 72 mm median (83 mm with --no-floor); the reference is MediaPipe's own landmarks
    # triangulated, consistency rather than truth.
    assert np.nanmedian(errors) < 100.0, np.nanmedian(errors)


def test_blender_imports_every_frame_of_both_takes(four: Take, single: Take) -> None:
    blender = require_blender()
    results = blender_bvh_positions(blender, [four.bvh, single.bvh], four.bvh.parent / "b.json")
    for take, result in zip((four, single), results, strict=True):
        frames = result["frame_end"] - result["frame_start"] + 1
        assert frames == take.frames == result["positions"].shape[0]
        assert all(name in result["bones"] for name in JOINT_NAMES)
        assert np.isfinite(result["positions"]).all()


def test_a_single_uncalibrated_video_stands_on_a_floor(single: Take) -> None:
    bvh = bvhio_positions_m(single.bvh, list(JOINT_NAMES))
    feet = [JOINT_NAMES.index("FootLeft"), JOINT_NAMES.index("FootRight")]
    assert abs(np.median(bvh[:, feet, 1].min(axis=1))) < 0.1  # the camera's height from the feet
    head = JOINT_NAMES.index("Head")
    # A person's head, not a child's or a giant's (the level-camera guess bends heights: the
    # clip's cameras look down about 25°, and the person crouches).
    assert 1.0 < np.median(bvh[:, head, 1]) < 2.1


# --- errors ----------------------------------------------------------------------------------


def test_a_missing_video_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["mocap", str(tmp_path / "nope.mp4"), "-o", str(tmp_path / "t.bvh")]) == 2
    assert "no such video" in capsys.readouterr().err


def test_several_videos_need_a_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert (
        main(["mocap", *_videos(), "--landmarks", str(LANDMARKS), "-o", str(tmp_path / "t.bvh")])
        == 2
    )
    assert "need --calibration" in capsys.readouterr().err


def test_intrinsics_with_a_calibration_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["mocap", "cam01.mp4", "--calibration", str(CALIBRATION), "--fov", "50"]
    assert main([*args, "--landmarks", str(LANDMARKS), "-o", str(tmp_path / "t.bvh")]) == 2
    assert "--intrinsics and --fov are for one video without --calibration" in (
        capsys.readouterr().err
    )


def test_a_missing_mono_environment_says_how_to_make_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    video = tmp_path / "cam01.mp4"
    video.write_bytes(b"")
    args = ["mocap", str(video), "--mono-python", str(tmp_path / "nope" / "python")]
    assert main([*args, "-o", str(tmp_path / "t.bvh")]) == 1
    assert "bash scripts/venv_mono.sh" in capsys.readouterr().err


def test_no_person_found_is_said(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with np.load(LANDMARKS) as data:
        arrays = {k: data[k] for k in data.files if k.startswith("cam01_")}
    arrays["cam01_detected"] = np.zeros_like(arrays["cam01_detected"])
    empty = tmp_path / "empty.npz"
    np.savez(empty, **arrays)
    status = main(["mocap", "cam01.mp4", "--landmarks", str(empty), "-o", str(tmp_path / "t.bvh")])
    assert status == 1
    assert "cam01.mp4: no person found in any of its 100 frames" in capsys.readouterr().err


def test_videos_named_otherwise_go_with_the_cameras_in_order(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    renamed = {"cam01": "front", "cam02": "left", "cam03": "back", "cam04": "right"}
    with np.load(LANDMARKS) as data:
        arrays = {renamed[k[:5]] + k[5:]: data[k] for k in data.files}
    landmarks = tmp_path / "renamed.npz"
    np.savez(landmarks, **arrays)
    videos = [f"{name}.mp4" for name in renamed.values()]
    args = ["mocap", *videos, "--calibration", str(CALIBRATION), "--video-fps", "60"]
    caplog.set_level("INFO", logger="skelfuse")
    assert main([*args, "--landmarks", str(landmarks), "-o", str(tmp_path / "t.bvh")]) == 0
    assert "matched by order" in caplog.text
    assert "back: clock +39.2 ms (+2.35 frames" in caplog.text  # cam03's lag, under its video


def test_a_video_without_its_camera_in_the_calibration_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["mocap", "cam01.mp4", "cam09.mp4", "--calibration", str(CALIBRATION)]
    assert main([*args, "--landmarks", str(LANDMARKS), "-o", str(tmp_path / "t.bvh")]) == 2
    assert "no camera for video cam09" in capsys.readouterr().err


# --- the real clip through the detector (mono environment) -----------------------------------


def _clip() -> Path:
    missing = [f for f in (*_videos(), "Calib.qca.txt") if not (CLIP / f).is_file()]
    if missing:
        unavailable(f"the real clip is not in {CLIP}: {missing}", "CI must provide it")
    return CLIP


def _mono() -> None:
    try:
        mono_python(None)
    except Exception as exc:  # MocapFailed: the message says how to make the environment
        unavailable(f"no mono environment: {exc}", "scripts/test.sh makes .venv-mono")


@pytest.mark.timeout(600)
def test_mocap_on_the_real_clip_detects_and_blender_imports_every_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clip = _clip()
    _mono()
    videos = [str(clip / v) for v in _videos()]
    four = _mocap(tmp_path / "four.bvh", *videos, "--calibration", str(clip / "Calib.qca.txt"),
                  "--keep-landmarks")  # fmt: skip
    err = capsys.readouterr().err
    assert "detecting: 400/400 frames (100 %)" in err
    assert (tmp_path / "four.landmarks.npz").is_file()
    one = _mocap(tmp_path / "one.bvh", videos[0], "--fov", "36")
    for take in (four, one):  # the C3D beside each BVH: the same frames in ezc3d
        markers = ezc3d_world_m(take.c3d, [f"P1_{n}" for n in JOINT_NAMES])
        assert markers.shape == (take.frames, len(JOINT_NAMES), 3)
        assert np.isfinite(markers).all()
    results = blender_bvh_positions(require_blender(), [four.bvh, one.bvh], tmp_path / "b.json")
    for take, result in zip((four, one), results, strict=True):
        assert result["frame_end"] - result["frame_start"] + 1 == take.frames >= 95
        assert np.isfinite(result["positions"]).all()
    with np.load(tmp_path / "four.landmarks.npz") as data:
        assert all(data[f"{n}_detected"].all() and float(data[f"{n}_fps"]) == 60.0 for n in CAMERAS)


def test_an_unreadable_video_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _mono()
    fake = tmp_path / "cam01.mp4"
    shutil.copy(ROOT / "README.md", fake)
    assert main(["mocap", str(fake), "-o", str(tmp_path / "t.bvh")]) == 1
    assert f"{fake}: not a video OpenCV can open" in capsys.readouterr().err
