"""Pose2Sim TOML and OpenCV FileStorage calibration files, the store's intrinsics, and
``skelfuse calibration import`` (calibration/camera_files.py, opencv_storage.py, store.py,
skelfuse/cli/calibration.py)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skelfuse.calibration.camera import Camera
from skelfuse.calibration.camera_files import (
    YUP_FROM_ZUP,
    as_sensor_calibrations,
    read_camera_file,
)
from skelfuse.calibration.errors import CameraFileError
from skelfuse.calibration.store import CalibrationFileError, CalibrationStore, SensorCalibration
from skelfuse.cli import calibration as cli
from skelfuse.cli.values import UsageError
from tests.unit.test_camera_triangulation import QCA, rig


def _toml_table(key: str, camera: Camera) -> str:
    """A camera as Pose2Sim writes it (``calib_qca_to_toml``'s layout), world Z up."""
    k = camera.intrinsics
    opencv_from_world = camera.T_opencv_from_world @ YUP_FROM_ZUP  # Z-up world → camera
    rvec = [float(v) for v in Rotation.from_matrix(opencv_from_world[:3, :3]).as_rotvec()]
    t = [float(v) for v in opencv_from_world[:3, 3]]
    return (
        f'[{key}]\nname = "{camera.name}"\nsize = [ {k.width}.0, {k.height}.0,]\n'
        f"matrix = [ [ {k.fx}, 0.0, {k.cx},], [ 0.0, {k.fy}, {k.cy},], [ 0.0, 0.0, 1.0,],]\n"
        f"distortions = [ {', '.join(str(v) for v in k.distortion[:4])},]\n"
        f"rotation = [ {rvec[0]!r}, {rvec[1]!r}, {rvec[2]!r},]\n"
        f"translation = [ {t[0]!r}, {t[1]!r}, {t[2]!r},]\nfisheye = false\n\n"
    )


def test_pose2sim_toml_agrees_with_the_qualisys_file(tmp_path: Path) -> None:
    """Pose2Sim's own conversion of a .qca.txt is its TOML: both readers place each camera
    at the same pose (they are written from different conventions: Qualisys' camera pose and
    axes, Pose2Sim's OpenCV world → camera Rodrigues)."""
    cameras = read_camera_file(QCA, "qualisys").cameras
    text = "".join(_toml_table(f"cam_{i + 1}", c) for i, c in enumerate(cameras))
    path = tmp_path / "Calib.toml"
    path.write_text(text + "[metadata]\nadjusted = false\nerror = 0.0\n")
    again = read_camera_file(path, "pose2sim").cameras
    assert [c.name for c in again] == [c.name for c in cameras]
    for a, b in zip(cameras, again, strict=True):
        np.testing.assert_allclose(b.T_world_from_sensor, a.T_world_from_sensor, atol=1e-9)
        assert b.intrinsics.distortion == a.intrinsics.distortion[:4]
    kept = read_camera_file(path, "pose2sim", up="y").cameras[0]
    np.testing.assert_allclose(
        YUP_FROM_ZUP @ kept.T_world_from_sensor, cameras[0].T_world_from_sensor, atol=1e-9
    )


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[cam_1\nname = 1", "not valid TOML"),
        ("[cam_1]\nname = 'a'\n", "missing size"),
        ("[cam_1]\nsize = [1, 2, 3]\n", "size must have shape"),
        ("[cam_1]\nfisheye = true\n", "fisheye"),
        ("[metadata]\nerror = 0.0\n", "no camera found"),
        ("cam_1 = 3\n", "expected a table"),
    ],
)
def test_pose2sim_broken_files(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "broken.toml"
    path.write_text(text)
    with pytest.raises(CameraFileError, match=message):
        read_camera_file(path, "pose2sim")


def test_pose2sim_bad_rotation(tmp_path: Path) -> None:
    table = _toml_table("cam_1", rig()[0])
    path = tmp_path / "bad.toml"
    path.write_text(table.replace("rotation = [", "rotation = [ 1.0, 2.0,]\nold = ["))
    with pytest.raises(CameraFileError, match=r"\[cam_1\].*rotation must have shape"):
        read_camera_file(path, "pose2sim")


OPENCV_YAML = """%YAML:1.0
---
image_width: 1088
image_height: 1920
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ {fx}, 0., {cx}, 0., {fy}, {cy}, 0., 0.,
       1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.05, 0.14, 6.0e-04, -5.0e-04, 0. ]
rvec: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ {r0}, {r1}, {r2} ]
tvec: !!opencv-matrix
   rows: 3
   cols: 1
   dt: d
   data: [ {t0}, {t1}, {t2} ]
"""

OPENCV_XML = """<?xml version="1.0"?>
<opencv_storage>
<image_width>1088</image_width>
<image_height>1920</image_height>
<camera_matrix type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    {fx} 0. {cx} 0. {fy} {cy}
    0. 0. 1.</data></camera_matrix>
<distortion_coefficients type_id="opencv-matrix">
  <rows>5</rows><cols>1</cols><dt>d</dt>
  <data>-0.05 0.14 6.0e-04 -5.0e-04 0.</data></distortion_coefficients>
<rvec type_id="opencv-matrix"><rows>3</rows><cols>1</cols><dt>d</dt>
  <data>{r0} {r1} {r2}</data></rvec>
<tvec type_id="opencv-matrix"><rows>3</rows><cols>1</cols><dt>d</dt>
  <data>{t0} {t1} {t2}</data></tvec>
</opencv_storage>
"""


def _fill(template: str, camera: Camera) -> str:
    k = camera.intrinsics
    transform = camera.T_opencv_from_world
    r = Rotation.from_matrix(transform[:3, :3]).as_rotvec()
    t = transform[:3, 3]
    return template.format(
        fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy, r0=r[0], r1=r[1], r2=r[2], t0=t[0], t1=t[1], t2=t[2]
    )


@pytest.mark.parametrize(("template", "suffix"), [(OPENCV_YAML, "yml"), (OPENCV_XML, "xml")])
def test_opencv_storage_yaml_and_xml(tmp_path: Path, template: str, suffix: str) -> None:
    camera = rig()[2]
    path = tmp_path / f"phone.{suffix}"
    path.write_text(_fill(template, camera))
    found = read_camera_file(path, "opencv")
    assert found.warnings == []
    (read,) = found.cameras
    assert read.name == "phone"
    assert read.intrinsics == camera.intrinsics
    np.testing.assert_allclose(read.T_world_from_sensor, camera.T_world_from_sensor, atol=1e-9)


def test_opencv_several_cameras_and_assumptions(tmp_path: Path) -> None:
    """EasyMocap's intri.yml layout: names and suffixed keys; no size, no extrinsics."""
    text = (
        '%YAML:1.0\n---\nnames:\n  - "1"\n  - "2"\n'
        "K_1: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
        "  data: [1000., 0., 320., 0., 1000., 240., 0., 0., 1.]\n"
        "dist_1: !!opencv-matrix\n  rows: 1\n  cols: 4\n  dt: d\n  data: [0.1, 0., 0., 0.]\n"
        "K_2: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n"
        "  data: [900., 0., 640., 0., 900., 360., 0., 0., 1.]\n"
    )
    path = tmp_path / "intri.yml"
    path.write_text(text)
    found = read_camera_file(path, "opencv")
    assert [c.name for c in found.cameras] == ["1", "2"]
    assert (found.cameras[1].intrinsics.width, found.cameras[1].intrinsics.height) == (1280, 720)
    assert found.cameras[0].intrinsics.distortion == (0.1, 0.0, 0.0, 0.0)
    assert sum("no image size" in w for w in found.warnings) == 2
    assert sum("no extrinsics" in w for w in found.warnings) == 2


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("%YAML:1.0\n---\n", "empty file"),
        ("%YAML:1.0\nimage_width: 10\n", "none of the keys camera_matrix"),
        ("%YAML:1.0\nK: [1, 2,\n", "never closes"),
        ("%YAML:1.0\nK: !!opencv-matrix\n  rows: 3\n  cols: 3\n  data: [1, 2]\n", "2 values"),
        ("%YAML:1.0\n  ::: nonsense\n", "expected 'key: value'"),
        ("<opencv_storage><K>1 2 3</K></opencv_storage>", "camera matrix must have shape"),
        ("<other/>", "not <opencv_storage>"),
        ("<opencv_storage>", "not valid XML"),
    ],
)
def test_opencv_broken_files(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "broken.yml"
    path.write_text(text)
    with pytest.raises(CameraFileError, match=message):
        read_camera_file(path, "opencv")


def test_store_keeps_intrinsics_and_lag(tmp_path: Path) -> None:
    found = read_camera_file(QCA, "qualisys")
    sensors = as_sensor_calibrations(found, "qualisys", rename={"cam03": "phone-3"})
    assert set(sensors) == {"cam01", "cam02", "phone-3", "cam04"}
    sensors["phone-3"] = SensorCalibration(
        sensors["phone-3"].T_world_from_sensor,
        "import:qualisys",
        None,
        {},
        found.cameras[2].intrinsics,
        0.039,
    )
    store = CalibrationStore(tmp_path)
    store.save(sensors)
    loaded = store.load()
    assert loaded is not None
    assert loaded.sensors["phone-3"].intrinsics == found.cameras[2].intrinsics
    assert loaded.sensors["phone-3"].lag_s == pytest.approx(0.039)
    assert loaded.sensors["cam01"].residual_mm == pytest.approx(0.402)
    # A sensor without them writes no such keys: older files and readers are unchanged.
    plain = json.loads(store.path.read_text())
    store.save({"kinect": SensorCalibration(np.eye(4), "points")})
    written = json.loads(store.path.read_text())["sensors"]
    assert "intrinsics" not in written["kinect"] and "lag_s" not in written["kinect"]
    assert "intrinsics" in plain["sensors"]["cam01"] and "lag_s" not in plain["sensors"]["cam01"]
    plain["sensors"]["cam01"]["intrinsics"]["fx"] = -1.0
    with pytest.raises(CalibrationFileError, match=r"cam01.*focal"):
        store.import_json(plain)
    with pytest.raises(CameraFileError, match="no camera named nope"):
        as_sensor_calibrations(found, "qualisys", rename={"nope": "x"})
    with pytest.raises(CameraFileError, match="share a sensor id"):
        as_sensor_calibrations(found, "qualisys", rename={"cam01": "cam02"})


def _run(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    cli.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["calibration", "import", *argv])
    result: int = args.func(args)
    return result


def test_cli_import(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "data"
    store = CalibrationStore(data)
    store.save({"kinect-a": SensorCalibration(np.eye(4), "points")})
    assert _run(str(QCA), "--format", "qualisys", "--data", str(data), "--dry-run") == 0
    assert store.load() is not None and set(store.load().sensors) == {"kinect-a"}  # type: ignore[union-attr]
    assert (
        _run(str(QCA), "--format", "qualisys", "--data", str(data), "--sensor", "cam01=rgb-1") == 0
    )
    loaded = store.load()
    assert loaded is not None and loaded.version == 2
    assert set(loaded.sensors) == {"kinect-a", "rgb-1", "cam02", "cam03", "cam04"}
    assert loaded.sensors["cam02"].method == "import:qualisys"
    assert loaded.sensors["rgb-1"].intrinsics is not None
    out = capsys.readouterr().out
    assert "rgb-1: at x" in out and "1088x1920 px" in out and "saved calibration version 2" in out
    broken = tmp_path / "broken.qca.txt"
    broken.write_text("<calibration><cameras><camera serial='x'/></cameras></calibration>")
    with pytest.raises(UsageError, match="missing <fov_video>"):
        _run(str(broken), "--format", "qualisys", "--data", str(data))
    with pytest.raises(UsageError, match="CAMERA=SENSOR_ID"):
        _run(str(QCA), "--format", "qualisys", "--data", str(data), "--sensor", "cam01")
    assert store.load().version == 2  # type: ignore[union-attr]  # nothing saved by failures


def test_skelfuse_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Through ``skelfuse``'s own parser: registered, and a broken file exits 2 naming it."""
    from skelfuse.cli import main

    assert main(["calibration", "import", str(QCA), "--format", "qualisys", "--dry-run"]) == 0
    assert "cam04: at x" in capsys.readouterr().out
    broken = tmp_path / "broken.toml"
    broken.write_text("[cam_1]\nname = 'a'\n")
    assert main(["calibration", "import", str(broken), "--format", "pose2sim"]) == 2
    assert "missing size" in capsys.readouterr().err
