"""agent.sim.mocap and its parts: BVH and ASF/AMC forward kinematics, the Kinect v2 mapping."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.sim.asf_amc import asf_amc_points
from skelfuse.agent.sim.clip import MocapFormatError, MotionClip
from skelfuse.agent.sim.mocap import FOOT_JOINT_FLOOR_HEIGHT_M, bvh_points, load_asf_amc, load_bvh
from skelfuse.protocol.skeleton import BONES, JOINT_COUNT, JOINT_NAMES, JointId as J, bone_lengths
from tests.support import unavailable

DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "cmu-mocap"
UP = np.array([0.0, 1.0, 0.0])


# --- shared data (skipped, visibly, when the samples are not there) -----------------------------


@pytest.fixture(scope="module")
def data_dir() -> Path:
    files = ("02.asf", "02_01.amc", "scaled_131_01.bvh")
    missing = [f for f in files if not (DATA_DIR / f).is_file()]
    if missing:
        unavailable(f"CMU mocap samples not found: {missing} in {DATA_DIR}", "CI must provide them")
    return DATA_DIR


@pytest.fixture(scope="module")
def walk_clip(data_dir: Path) -> MotionClip:
    return load_asf_amc(data_dir / "02.asf", data_dir / "02_01.amc")


@pytest.fixture(scope="module")
def bvh_clip(data_dir: Path) -> MotionClip:
    return load_bvh(data_dir / "scaled_131_01.bvh")


@pytest.fixture(params=["walk_clip", "bvh_clip"])
def clip(request: pytest.FixtureRequest) -> MotionClip:
    result: MotionClip = request.getfixturevalue(request.param)
    return result


def _f64(clip: MotionClip) -> npt.NDArray[np.float64]:
    return clip.joints_m.astype(np.float64)


def test_shapes_dtypes_fps_and_frame_counts(walk_clip: MotionClip, bvh_clip: MotionClip) -> None:
    assert walk_clip.joints_m.shape == (343, JOINT_COUNT, 3)
    assert bvh_clip.joints_m.shape == (995, JOINT_COUNT, 3)
    for c in (walk_clip, bvh_clip):
        assert c.joints_m.dtype == np.float32
        assert c.fps == 120.0  # BVH "Frame Time: 0.008333" is 1/120 printed to 6 decimals
        assert np.all(np.isfinite(c.joints_m))
    assert walk_clip.name == "02_01"
    assert bvh_clip.name == "scaled_131_01"
    assert walk_clip.duration_s == pytest.approx(342 / 120)
    assert bvh_clip.duration_s == pytest.approx(994 / 120)


def test_bone_lengths_are_rigid(clip: MotionClip) -> None:
    lengths = bone_lengths(clip.joints_m)
    cv = lengths.std(axis=0) / lengths.mean(axis=0)
    worst = int(np.argmax(cv))
    parent, child = BONES[worst]
    assert cv.max() < 0.01, f"{JOINT_NAMES[parent]}-{JOINT_NAMES[child]} varies, CV {cv.max():.3%}"
    assert lengths.min() > 0.02  # no two joints collapsed onto each other


def test_height_plausible_and_spine_ordered(clip: MotionClip) -> None:
    joints = _f64(clip)
    # Both clips start standing upright; the head joint is the head's centre.
    head_y = joints[:, J.HEAD, 1]
    assert 1.4 <= head_y.max() <= 1.8, f"head centre peaks at {head_y.max():.3f} m"
    assert 1.35 <= head_y[0] <= 1.8, f"head centre at {head_y[0]:.3f} m in the first frame"
    chain = [J.SPINE_BASE, J.SPINE_MID, J.SPINE_SHOULDER, J.NECK, J.HEAD]
    assert np.all(np.diff(joints[0, chain, 1]) > 0.05), joints[0, chain, 1]
    assert 0.8 < joints[0, J.SPINE_BASE, 1] < 1.1


def test_feet_on_the_floor(clip: MotionClip) -> None:
    joints = _f64(clip)
    feet_y = joints[:, [J.FOOT_LEFT, J.FOOT_RIGHT], 1]
    ankles_y = joints[:, [J.ANKLE_LEFT, J.ANKLE_RIGHT], 1]
    assert feet_y.min() == pytest.approx(FOOT_JOINT_FLOOR_HEIGHT_M, abs=1e-6)
    assert 0.03 <= feet_y.min() <= 0.08
    assert 0.05 <= ankles_y.min() <= 0.12
    assert joints[..., 1].min() >= 0.0, "a joint under the floor"
    # Walking, never airborne: some foot is within 12 cm of the floor in almost every frame.
    assert (feet_y.min(axis=1) < 0.12).mean() > 0.98


def test_left_is_the_persons_left(clip: MotionClip) -> None:
    """Right-handed, +Y up: a person facing f has their left at up × f."""
    joints = _f64(clip)
    # Facing from anatomy alone (toes point forward), independent of the left/right labels.
    toes = [joints[:, foot] - joints[:, ankle] for ankle, foot in
            ((J.ANKLE_LEFT, J.FOOT_LEFT), (J.ANKLE_RIGHT, J.FOOT_RIGHT))]  # fmt: skip
    facing = sum(t / np.linalg.norm(t, axis=1, keepdims=True) for t in toes)
    facing[:, 1] = 0.0
    left_expected = np.cross(UP, facing)
    for left, right in ((J.HIP_LEFT, J.HIP_RIGHT), (J.SHOULDER_LEFT, J.SHOULDER_RIGHT)):
        side = np.einsum("ti,ti->t", joints[:, left] - joints[:, right], left_expected)
        assert side[0] > 0, f"{left.name} on the person's right in the first frame"
        assert (side > 0).mean() > 0.95, f"{left.name} on the person's right too often"
    # First frame: both subjects face about +Z, so their left is +X.
    assert facing[0, 2] > 0
    assert joints[0, J.HIP_LEFT, 0] > joints[0, J.HIP_RIGHT, 0]
    assert joints[0, J.HAND_LEFT, 0] > joints[0, J.HAND_RIGHT, 0]


def test_people_walk_forwards(clip: MotionClip) -> None:
    """Facing from the labels (left × up) agrees with the walking direction."""
    joints = _f64(clip)
    facing = np.cross(joints[:, J.HIP_LEFT] - joints[:, J.HIP_RIGHT], UP) + np.cross(
        joints[:, J.SHOULDER_LEFT] - joints[:, J.SHOULDER_RIGHT], UP
    )
    facing[:, 1] = 0.0
    facing /= np.linalg.norm(facing, axis=1, keepdims=True)
    velocity = np.gradient(joints[:, J.SPINE_BASE], axis=0) * clip.fps
    velocity[:, 1] = 0.0
    speed = np.linalg.norm(velocity, axis=1)
    moving = speed > 0.5
    assert moving.sum() > 100
    cos = np.einsum("ti,ti->t", velocity[moving], facing[moving]) / speed[moving]
    assert np.median(cos) > 0.8


def test_walk_moves(clip: MotionClip) -> None:
    root = _f64(clip)[:, J.SPINE_BASE]
    displacement = np.linalg.norm(root[-1, [0, 2]] - root[0, [0, 2]])
    assert displacement > 1.0


def test_walk_speed(walk_clip: MotionClip) -> None:
    root = _f64(walk_clip)[:, J.SPINE_BASE]
    speed = np.linalg.norm(root[-1, [0, 2]] - root[0, [0, 2]]) / walk_clip.duration_s
    assert 0.8 < speed < 1.6  # a normal walk, ~1.2 m/s


def test_loaded_clip_at_and_centred(walk_clip: MotionClip) -> None:
    np.testing.assert_allclose(walk_clip.at(10 / 120), walk_clip.joints_m[10], atol=1e-6)
    centred = walk_clip.centred()
    base = centred.joints_m[:, J.SPINE_BASE].astype(np.float64)
    np.testing.assert_allclose(base[:, [0, 2]].mean(axis=0), 0.0, atol=1e-5)
    np.testing.assert_allclose(centred.joints_m[..., 1], walk_clip.joints_m[..., 1])
    np.testing.assert_allclose(bone_lengths(centred.joints_m), bone_lengths(walk_clip.joints_m),
                               atol=1e-5)  # fmt: skip


def test_points_cover_the_file_skeletons(data_dir: Path) -> None:
    asf = asf_amc_points(data_dir / "02.asf", data_dir / "02_01.amc")
    assert asf.positions.shape == (343, 31, 3)  # root + 30 bones
    bvh = bvh_points(data_dir / "scaled_131_01.bvh")
    assert bvh.positions.shape == (995, 38, 3)  # 31 joints + 7 End Sites
    assert bvh.fps == 120.0
    assert bvh.parents[bvh.names.index("LeftKnee")] == bvh.names.index("LeftHip")


# --- MotionClip (no data needed) ----------------------------------------------------------------


def _random_clip(frames: int = 4, fps: float = 10.0) -> MotionClip:
    rng = np.random.default_rng(7)
    joints = rng.normal(size=(frames, JOINT_COUNT, 3)).astype(np.float32)
    return MotionClip(joints_m=joints, fps=fps, name="random")


def test_at_interpolates_between_frames() -> None:
    clip = _random_clip()
    j = clip.joints_m.astype(np.float64)
    assert clip.duration_s == pytest.approx(0.3)
    for i in range(3):
        np.testing.assert_allclose(clip.at((i + 0.5) / 10), (j[i] + j[i + 1]) / 2, atol=1e-6)
        np.testing.assert_allclose(clip.at(i / 10), j[i], atol=1e-6)
    np.testing.assert_allclose(clip.at(0.125), 0.75 * j[1] + 0.25 * j[2], atol=1e-6)
    out = clip.at(0.05)
    assert out.shape == (JOINT_COUNT, 3)
    assert out.dtype == np.float64


def test_at_clamps_without_looping() -> None:
    clip = _random_clip()
    j = clip.joints_m.astype(np.float64)
    np.testing.assert_array_equal(clip.at(-1.0), j[0])
    np.testing.assert_array_equal(clip.at(0.3), j[3])
    np.testing.assert_array_equal(clip.at(0.35), j[3])
    np.testing.assert_array_equal(clip.at(1e9), j[3])
    single = _random_clip(frames=1)
    assert single.duration_s == 0.0
    np.testing.assert_array_equal(single.at(0.5), single.joints_m[0])
    with pytest.raises(ValueError, match="finite"):
        clip.at(float("nan"))


def test_centred_moves_only_horizontally() -> None:
    clip = _random_clip()
    centred = clip.centred()
    base = centred.joints_m[:, J.SPINE_BASE].astype(np.float64)
    np.testing.assert_allclose(base[:, [0, 2]].mean(axis=0), 0.0, atol=1e-6)
    np.testing.assert_array_equal(centred.joints_m[..., 1], clip.joints_m[..., 1])
    assert centred.joints_m.dtype == np.float32
    assert (centred.fps, centred.name) == (clip.fps, clip.name)
    delta = centred.joints_m.astype(np.float64) - clip.joints_m
    np.testing.assert_allclose(delta - delta[0, 0], 0.0, atol=1e-6)  # one rigid shift


def test_motion_clip_validates() -> None:
    with pytest.raises(ValueError, match="float32"):
        MotionClip(joints_m=np.zeros((2, 25, 3)), fps=30.0, name="x")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\(T >= 1, 25, 3\)"):
        MotionClip(joints_m=np.zeros((2, 24, 3), np.float32), fps=30.0, name="x")
    with pytest.raises(ValueError, match="fps"):
        MotionClip(joints_m=np.zeros((2, 25, 3), np.float32), fps=0.0, name="x")


# --- forward kinematics on tiny hand-written files (no data needed) -----------------------------

TINY_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Arm
  {
    OFFSET 1 0 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 2 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.033333
0 0 0  0 0 0   0 0 0
10 20 30  90 0 0   0 0 90
0 0 0  0 0 0   90 0 90
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_tiny_bvh_forward_kinematics(tmp_path: Path) -> None:
    points = bvh_points(_write(tmp_path, "tiny.bvh", TINY_BVH))
    assert points.names == ("Hips", "Arm", "Arm.end")
    assert points.parents == (-1, 0, 1)
    assert points.fps == 30.0
    expected = np.array(
        [
            # rest pose: offsets add up
            [[0, 0, 0], [1, 0, 0], [1, 2, 0]],
            # root at (10, 20, 30) turned 90° about Z: the arm offset +X becomes +Y; the arm's
            # own 90° about X then turns the end offset +Y to +Z, and the root's Rz keeps +Z.
            [[10, 20, 30], [10, 21, 30], [10, 21, 32]],
            # arm Rz(90)·Rx(90) in channel order Z, Y, X: +Y -> +Z (Rx) -> +Z (Rz)
            [[0, 0, 0], [1, 0, 0], [1, 0, 2]],
        ],
        dtype=np.float64,
    )
    np.testing.assert_allclose(points.positions, expected, atol=1e-12)


def test_bvh_rotation_follows_the_channel_order(tmp_path: Path) -> None:
    text = TINY_BVH.replace(
        "CHANNELS 3 Zrotation Yrotation Xrotation", "CHANNELS 3 Xrotation Yrotation Zrotation"
    )
    points = bvh_points(_write(tmp_path, "order.bvh", text))
    # frame 2 now reads X=90, Z=90: R = Rx(90)·Rz(90); +Y -> -X (Rz) -> -X (Rx)
    np.testing.assert_allclose(points.positions[2, 2], [-1, 0, 0], atol=1e-12)
    # frame 1: X=0, Z=90 on the arm; the root's Rz(90) then turns -X into -Y
    np.testing.assert_allclose(points.positions[1, 2], [10, 21 - 2, 30], atol=1e-12)


TINY_ASF = """:version 1.10
:name tiny
:units
  mass 1.0
  length 0.45
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name b1
     direction 1 0 0
     length 45
     axis 0 0 90  XYZ
    dof rx
    limits (-180.0 180.0)
  end
  begin
     id 2
     name b2
     direction 0 1 0
     length 0.45
     axis 0 0 0  XYZ
    dof rz
  end
:hierarchy
  begin
    root b1
    b1 b2
  end
"""

TINY_AMC = """# tiny
:FULLY-SPECIFIED
:DEGREES
1
root 0 0 0 0 0 0
b1 0
b2 0
2
root 4.5 0 0 0 0 0
b1 90
b2 90
3
root 0 0 0 90 0 90
b1 0
b2 0
"""


def test_tiny_asf_amc_forward_kinematics(tmp_path: Path) -> None:
    points = asf_amc_points(
        _write(tmp_path, "tiny.asf", TINY_ASF), _write(tmp_path, "tiny.amc", TINY_AMC), fps=60.0
    )
    assert points.names == ("root", "b1", "b2")
    assert points.fps == 60.0
    inch = 0.0254  # length 0.45: 0.45 units = 1 inch; b1 is 100 inches, b2 one inch
    b1 = 100 * inch
    expected = np.array(
        [
            [[0, 0, 0], [b1, 0, 0], [b1, inch, 0]],
            # root moved 10 inches along X. b1: C = Rz(90) turns its rx into a rotation about +Y,
            # so L = Ry(90) takes +X to -Z. b2: R = Ry(90)·Rz(90) takes +Y to -X, then to +Z.
            [[10 * inch, 0, 0], [10 * inch, 0, -b1], [10 * inch, 0, -b1 + inch]],
            # root RX = RZ = 90 with axis XYZ: R = Rz(90)·Rx(90); +X -> +X -> +Y for b1,
            # +Y -> +Z -> +Z for b2
            [[0, 0, 0], [0, b1, 0], [0, b1, inch]],
        ],
        dtype=np.float64,
    )
    np.testing.assert_allclose(points.positions, expected, atol=1e-12)


def test_asf_axis_values_pair_with_the_order_letters(tmp_path: Path) -> None:
    amc = _write(tmp_path, "tiny.amc", TINY_AMC)
    xyz = asf_amc_points(_write(tmp_path, "xyz.asf", TINY_ASF), amc)
    zyx = asf_amc_points(
        _write(tmp_path, "zyx.asf", TINY_ASF.replace("axis 0 0 90  XYZ", "axis 90 0 0 ZYX")), amc
    )
    np.testing.assert_allclose(zyx.positions, xyz.positions, atol=1e-12)


def test_loaded_clips_are_read_only(walk_clip: MotionClip) -> None:
    with pytest.raises(ValueError, match="read-only"):
        walk_clip.joints_m[0, 0, 0] = 1.0


# --- malformed and unsupported files ------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            TINY_BVH.replace("0 0 0   90 0 90", "0 0 0   90 0"),
            r"tiny\.bvh:21: frame 2 has 8 values",
        ),
        (TINY_BVH.replace("Frames: 3", "Frames: 4"), "header says 4 frames, found 3"),
        (TINY_BVH.replace("10 20 30", "10 abc 30"), r":20: expected a number, got 'abc'"),
        (TINY_BVH.replace("MOTION", "MOTON"), "no MOTION section"),
        (TINY_BVH.replace("Xrotation\n  JOINT", "Wrotation\n  JOINT"), "unsupported channel"),
        (TINY_BVH.replace("OFFSET 1 0 0", "OFFSET 1 0"), r":8: expected a number, got 'CHANNELS'"),
        (TINY_BVH.replace("    }\n  }\n}", "    }\n  }\n"), "hierarchy ends early"),
        (TINY_BVH.replace("Frame Time: 0.033333", ""), "expected 'Frames: N' and 'Frame Time: dt'"),
        ("", "no MOTION section"),
    ],
)
def test_malformed_bvh_raises(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(MocapFormatError, match=message):
        bvh_points(_write(tmp_path, "tiny.bvh", text))


def test_bvh_without_the_cmu_joints_is_unsupported(tmp_path: Path) -> None:
    with pytest.raises(MocapFormatError, match=r"unsupported skeleton, no point named 'Chest'"):
        load_bvh(_write(tmp_path, "tiny.bvh", TINY_BVH))


def test_binary_file_raises(tmp_path: Path) -> None:
    path = tmp_path / "x.bvh"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(MocapFormatError, match="not a text file"):
        bvh_points(path)


@pytest.mark.parametrize(
    ("asf", "amc", "message"),
    [
        (TINY_ASF, TINY_AMC.replace("b2 90", "b3 90"), r"tiny\.amc:11: bone 'b3' is not in"),
        (TINY_ASF, TINY_AMC.replace("b1 90", "b1 90 5"), "'b1' has 2 values, expected 1"),
        (TINY_ASF, TINY_AMC.replace("3\nroot", "4\nroot"), "frame 4 follows frame 2"),
        (TINY_ASF, TINY_AMC.replace("root 4.5 0 0 0 0 0\n", ""), r"frame 1 \(counting from 0\)"),
        (TINY_ASF, "# nothing\n", "no frames"),
        (TINY_ASF.replace("dof rz", "dof rz l"), TINY_AMC, "unsupported dof 'rz l'"),
        (TINY_ASF.replace("    b1 b2\n", ""), TINY_AMC, r"not connected to root.*'b2'"),
        (TINY_ASF.replace("direction 0 1 0", "direction 0 1"), TINY_AMC, "expected 3 numbers"),
        (TINY_ASF.replace(":hierarchy", ":hierarchx"), TINY_AMC, "missing :bonedata or :hier"),
        (TINY_ASF.replace("axis 0 0 0  XYZ", "axis 0 0 0 XXY"), TINY_AMC, "permutation of XYZ"),
    ],
)
def test_malformed_asf_amc_raises(tmp_path: Path, asf: str, amc: str, message: str) -> None:
    with pytest.raises(MocapFormatError, match=message):
        asf_amc_points(_write(tmp_path, "tiny.asf", asf), _write(tmp_path, "tiny.amc", amc))


@pytest.mark.parametrize(
    ("frame_time", "fps"),
    [("0.008333", 120.0), ("0.0333333", 30.0), ("0.01", 100.0), ("0.03", 1 / 0.03)],
)
def test_fps_from_the_printed_frame_time(tmp_path: Path, frame_time: str, fps: float) -> None:
    text = TINY_BVH.replace("0.033333", frame_time)
    assert bvh_points(_write(tmp_path, "t.bvh", text)).fps == pytest.approx(fps, rel=1e-12)
