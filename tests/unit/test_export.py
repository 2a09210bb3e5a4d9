"""Exports: BVH round trip, CSV/JSON tables, C3D (Z up, mm, residual −1 for missing)."""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.sim.mocap import load_asf_amc, load_bvh
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.protocol.bvh import parse_bvh
from skelfuse.protocol.skeleton import JOINT_NAMES
from skelfuse.protocol.transform import axis_rotation
from skelfuse.recording.bvh_rig import NODES
from skelfuse.recording.export_bvh import bvh_from_joints, euler_zxy_deg, roundtrip_errors_m
from skelfuse.recording.export_c3d import export_c3d, read_c3d, z_up_mm
from skelfuse.recording.export_table import csv_header, export_csv, export_json
from skelfuse.recording.take import PersonTrack, Take, TakeError, resample, take_from_jsonl


def _track(
    joints: np.ndarray, fps: float = 30.0, person_id: int = 1, first: int = 0
) -> PersonTrack:
    times = 1_800_000_000.0 + (first + np.arange(joints.shape[0])) / fps
    confidence = np.where(np.isfinite(joints).all(axis=2), 0.9, 0.0)
    return PersonTrack(person_id, times, joints, confidence)


def test_bvh_round_trip_within_1_cm_on_cmu_motion(cmu_dir: Path) -> None:
    for clip in (load_bvh(cmu_dir / "scaled_131_01.bvh"),
                 load_asf_amc(cmu_dir / "02.asf", cmu_dir / "02_01.amc")):  # fmt: skip
        joints = clip.joints_m.astype(np.float64)[::2]
        errors = roundtrip_errors_m(joints, bvh_from_joints(joints, clip.fps / 2))
        assert errors.max() < 0.01, f"{clip.name}: max {errors.max() * 1000:.1f} mm"


def test_bvh_round_trip_on_the_simulator_routine_with_missing_joints() -> None:
    performer = ProceduralPerformer(1)
    joints = np.stack([performer.joints_at(t)[0] for t in np.arange(0, 27, 1 / 15)])
    joints[10:14, 7] = np.nan  # a hand lost for a few frames
    joints[40, :] = np.nan  # a whole frame lost
    text = bvh_from_joints(joints, 15.0)
    errors = roundtrip_errors_m(joints, text)
    assert errors.max() < 0.01 and errors.size == np.isfinite(joints[..., 0]).sum()
    bvh = parse_bvh(text)
    assert [j.name for j in bvh.joints if j.name in JOINT_NAMES] == [
        n.name for n in NODES if n.child is None
    ]
    assert bvh.motion.shape[0] == joints.shape[0] and bvh.frame_time_s == pytest.approx(1 / 15)


def test_bvh_stretch_mode_reproduces_noisy_bone_lengths() -> None:
    performer = ProceduralPerformer(1)
    rng = np.random.default_rng(0)
    joints = np.stack([performer.joints_at(t)[0] for t in np.arange(0, 5, 1 / 30)])
    joints += rng.normal(scale=0.01, size=joints.shape)
    assert roundtrip_errors_m(joints, bvh_from_joints(joints, 30, stretch=True)).max() < 1e-4


def test_euler_zxy_inverts_rotation_matrices() -> None:
    rng = np.random.default_rng(2)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    rotation = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)  # fmt: skip
    angles = euler_zxy_deg(rotation)
    radians = np.radians(angles)
    rebuilt = (axis_rotation("z", radians[:, 0]) @ axis_rotation("x", radians[:, 1])
               @ axis_rotation("y", radians[:, 2]))  # fmt: skip
    np.testing.assert_allclose(rebuilt, rotation, atol=1e-9)


def test_resample_interpolates_and_leaves_gaps_empty() -> None:
    joints = np.zeros((4, 25, 3))
    joints[:, :, 0] = np.arange(4)[:, None]
    track = PersonTrack(1, np.array([0.0, 0.1, 0.2, 1.0]), joints, np.ones((4, 25)))
    times, out, confidence = resample(track, 20.0)
    assert times.size == 21
    assert out[1, 0, 0] == pytest.approx(0.5) and np.isnan(out[10, 0, 0])
    assert confidence[10, 0] == 0 and out[20, 0, 0] == 3


EPOCH = 1_795_000_000.123456


def _moving_track(times_s: np.ndarray, person_id: int = 1) -> PersonTrack:
    """Every joint moves in a straight line at a joint-specific speed (metres, per second since
    EPOCH), so linear interpolation must give the motion exactly at any instant."""
    since = times_s - EPOCH
    speeds = np.linspace(0.2, 1.5, 25)[:, None] * np.array([1.0, -0.3, 0.6])
    joints = np.array([0.1, 1.0, 2.0]) + since[:, None, None] * speeds
    return PersonTrack(person_id, times_s, joints, np.full(joints.shape[:2], 0.8))


def _motion_at(times_s: np.ndarray) -> np.ndarray:
    return _moving_track(np.asarray(times_s, dtype=np.float64)).joints


def _jittered_times(count: int, fps: float = 30.0, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return EPOCH + 0.0123 + np.arange(count) / fps + rng.uniform(-0.004, 0.004, count)


def test_resample_on_epoch_seconds_interpolates_between_jittered_fused_instants() -> None:
    track = _moving_track(_jittered_times(90))
    times, joints, confidence = resample(track, 60.0)
    assert times[0] == track.times_s[0] and np.diff(times) == pytest.approx(1 / 60, abs=1e-6)
    assert times.size == int((track.times_s[-1] - track.times_s[0]) * 60) + 1
    # Epoch-scale times must not pass as "on a fused instant" (rtol on 1.8e9 s is 5 h): each
    # frame is the motion at its own instant, no frame repeats its neighbour.
    np.testing.assert_allclose(joints, _motion_at(times), atol=1e-6)
    assert (np.abs(np.diff(joints, axis=0)).max(axis=(1, 2)) > 0).all()
    assert (confidence == 0.8).all()


def test_resample_leaves_gaps_over_the_limit_empty_and_bridges_shorter_ones() -> None:
    times = _jittered_times(120)
    since = times - times[0]
    keep = ~(((since > 1.0) & (since < 1.5)) | ((since > 0.5) & (since < 0.6)))
    track = _moving_track(times[keep])
    grid, joints, confidence = resample(track, 60.0)
    rel = grid - track.times_s[0]
    kept = since[keep]
    last_before, first_after = kept[kept <= 1.0].max(), kept[kept >= 1.5].min()
    assert first_after - last_before > 0.25  # the long gap
    inside = (rel > last_before + 1e-6) & (rel < first_after - 1e-6)
    assert inside.sum() >= 25
    assert np.isnan(joints[inside]).all() and (confidence[inside] == 0).all()
    np.testing.assert_allclose(joints[~inside], _motion_at(grid[~inside]), atol=1e-6)
    assert (confidence[~inside] == 0.8).all()


def test_resample_bridges_each_joint_from_its_own_samples() -> None:
    times = _jittered_times(60)
    track = _moving_track(times)
    track.joints[10:13, 7] = np.nan  # a hand unknown for 0.1 s: bridged
    track.joints[20:35, 3] = np.nan  # the head unknown for 0.5 s: left empty
    grid, joints, _ = resample(track, 30.0)
    hand_ok = np.isfinite(joints[:, 7]).all(axis=1)
    assert hand_ok.all()
    np.testing.assert_allclose(joints[:, 7], _motion_at(grid)[:, 7], atol=1e-6)
    rel = grid - times[0]
    head_gap = (rel > times[19] - times[0] + 1e-6) & (rel < times[35] - times[0] - 1e-6)
    assert np.isnan(joints[head_gap, 3]).all() and np.isfinite(joints[~head_gap, 3]).all()
    others = [j for j in range(25) if j != 3]
    np.testing.assert_allclose(joints[:, others], _motion_at(grid)[:, others], atol=1e-6)


def test_c3d_samples_every_person_on_the_takes_clock(tmp_path: Path) -> None:
    early = _moving_track(_jittered_times(60), person_id=1)
    late = _moving_track(_jittered_times(60, seed=4)[14:], person_id=4)  # joins 0.45 s in
    frames = export_c3d(Take({1: early, 4: late}), tmp_path / "t.c3d", fps=60.0)
    data = read_c3d(tmp_path / "t.c3d")
    clock = early.times_s[0] + np.arange(frames) / 60.0
    for k, person in enumerate((early, late)):
        points = data.points[:, k * 25 : (k + 1) * 25]
        present = (clock >= person.times_s[0] - 1e-6) & (clock <= person.times_s[-1] + 1e-6)
        assert np.isnan(points[~present]).all()
        expected = z_up_mm(_motion_at(clock[present]))
        np.testing.assert_allclose(points[present], expected, atol=0.05)  # float32 mm


def _take() -> Take:
    performer = ProceduralPerformer(2)
    joints = np.stack([performer.joints_at(t) for t in np.arange(0, 2, 1 / 30)])
    a, b = joints[:, 0].copy(), joints[:, 1].copy()
    a[5:15, 3] = np.nan  # the head unknown for 0.33 s: longer than resampling bridges
    return Take({1: _track(a, person_id=1), 4: _track(b[10:], person_id=4, first=10)})


def test_csv_and_json_carry_positions_and_confidences(tmp_path: Path) -> None:
    take = _take()
    rows = export_csv(take, tmp_path / "t.csv")
    with (tmp_path / "t.csv").open() as handle:
        table = list(csv.DictReader(handle))
    assert rows == len(table) == 60 + 50 and list(table[0]) == csv_header()
    row = next(r for r in table if r["person_id"] == "1" and float(r["t_s"]) > 1_800_000_000.16)
    assert row["Head_x"] == "" and row["Head_c"] == "0"
    assert float(row["SpineBase_c"]) == pytest.approx(0.9)
    export_json(take, tmp_path / "t.json")
    data = json.loads((tmp_path / "t.json").read_text())
    assert [p["id"] for p in data["persons"]] == [1, 4] and data["persons"][0]["joints"][5][
        3
    ] is None


def test_c3d_is_z_up_millimetres_with_invalid_markers(tmp_path: Path) -> None:
    take = _take()
    frames = export_c3d(take, tmp_path / "t.c3d", fps=30.0)
    data = read_c3d(tmp_path / "t.c3d")
    assert frames == 60 and data.rate_hz == 30.0 and len(data.labels) == 50
    assert data.labels[0] == "P1_SpineBase" and data.labels[25] == "P4_SpineBase"
    expected = z_up_mm(take.persons[1].joints[0, 0])
    np.testing.assert_allclose(data.points[0, 0], expected, atol=0.01)
    assert expected[2] > 500  # height is +Z
    assert np.isnan(data.points[5, 3]).all()  # unknown joint: residual -1
    assert np.isnan(data.points[:10, 25:]).all()  # person 4 not there yet
    c3d = pytest.importorskip("c3d")  # independent reader, when installed
    with (tmp_path / "t.c3d").open("rb") as handle, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "No analog data found"
        reader = c3d.Reader(handle)
        points = [p for _, p, _ in reader.read_frames()]
    assert len(points) == 60 and points[5][3][3] == -1
    np.testing.assert_allclose(points[0][0][:3], expected, atol=0.01)


def test_take_from_jsonl_and_empty_takes(tmp_path: Path) -> None:
    lines = [
        {"type": "skeleton"},
        {"type": "frame", "t": 1.0, "persons": [{"id": 2, "joints": [[0, 1, 2]] + [None] * 24,
                                                  "confidence": [1.0] + [0.0] * 24}]},
    ]  # fmt: skip
    path = tmp_path / "live.jsonl"
    path.write_text("\n".join(json.dumps(x) for x in lines))
    take = take_from_jsonl(path)
    assert take.main_person().person_id == 2 and np.isnan(take.persons[2].joints[0, 1]).all()
    with pytest.raises(TakeError, match="nobody"):
        Take({}).main_person()
