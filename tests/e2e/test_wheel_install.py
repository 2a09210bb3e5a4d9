"""The built wheel installs one top-level import package, ``skelfuse``, holding every layer.

Builds with scripts/build_wheel.sh (what scripts/smoke_wheel.sh and CI use) and installs it
without dependencies into a folder, then reads the installed distribution's file list. The full
install with the server extras, and a server started from it: scripts/smoke_wheel.sh."""

from __future__ import annotations

import subprocess
import sys
from importlib.metadata import distributions
from pathlib import Path, PurePosixPath

import pytest

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("geometry", "protocol", "agent", "calibration", "fusion", "recording", "server")


def _run(command: list[str]) -> None:
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, f"{' '.join(command)}:\n{done.stdout}\n{done.stderr}"


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[PurePosixPath]]:
    """The folder the wheel was installed into, and the files its RECORD lists."""
    tmp = tmp_path_factory.mktemp("wheel")
    _run(["bash", str(ROOT / "scripts" / "build_wheel.sh"), str(tmp / "dist")])
    (wheel,) = (tmp / "dist").glob("skelfuse-*.whl")
    site = tmp / "site"
    _run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-compile",
          "--target", str(site), str(wheel)])  # fmt: skip
    (dist,) = [d for d in distributions(path=[str(site)]) if d.metadata["Name"] == "skelfuse"]
    return site, [PurePosixPath(str(f)) for f in dist.files or []]


@pytest.mark.e2e
def test_the_install_adds_one_top_level_package(
    installed: tuple[Path, list[PurePosixPath]],
) -> None:
    site, files = installed
    # RECORD lists paths from site-packages: the console script sits outside it, at ../../../bin
    outside = [f for f in files if f.parts[0] == ".."]
    assert [(f.parts[-2], f.name) for f in outside] == [("bin", "skelfuse")]
    tops = {f.parts[0] for f in files if f not in outside}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"skelfuse"}
    assert [t.split("-")[0] for t in tops if t.endswith(".dist-info")] == ["skelfuse"]
    assert {p.name for p in site.iterdir() if not p.name.endswith(".dist-info")} == {
        "skelfuse",
        "bin",
    }


@pytest.mark.e2e
def test_every_source_module_and_viewer_file_is_installed(
    installed: tuple[Path, list[PurePosixPath]],
) -> None:
    _, files = installed
    shipped = {str(f) for f in files}
    expected = {
        f"skelfuse/{path.relative_to(ROOT / 'skelfuse').as_posix()}"
        for path in (ROOT / "skelfuse").rglob("*.py")
    }
    for layer in LAYERS:
        expected |= {
            f"skelfuse/{layer}/{path.relative_to(ROOT / layer).as_posix()}"
            for path in (ROOT / layer).rglob("*")
            if path.is_file() and "__pycache__" not in path.parts
        }
    assert len(expected) > 80
    assert not expected - shipped, f"not in the wheel: {sorted(expected - shipped)}"
