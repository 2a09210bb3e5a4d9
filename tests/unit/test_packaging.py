"""One import root: every package folder is mapped under ``skelfuse``, and nothing imports a layer
by its bare folder name (which only works from the repository root, and would pick up any other
installed ``server`` or ``protocol`` package). The built wheel: tests/e2e/test_wheel_install.py."""

from __future__ import annotations

import ast
import fnmatch
import os
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SETUPTOOLS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
PACKAGE_DIR: dict[str, str] = SETUPTOOLS["package-dir"]
LAYERS = {package.split(".")[1] for package in PACKAGE_DIR if package != "skelfuse"}
NOT_SHIPPED = {"tests", "bench", "scripts", "docs", "build", "dist"}  # never in the wheel
SKIPPED_DIRS = {"__pycache__", ".venv", ".git", "build", "dist", "node_modules"}


def _folder_of(package: str) -> Path:
    """The source folder setuptools reads ``package`` from (the longest package-dir prefix)."""
    parts = package.split(".")
    for cut in range(len(parts), 0, -1):
        prefix = ".".join(parts[:cut])
        if prefix in PACKAGE_DIR:
            return ROOT / PACKAGE_DIR[prefix] / Path(*parts[cut:])
    return ROOT / Path(*parts)


def _package_folders() -> dict[Path, str]:
    """Every folder under a mapped root -> the package name it must install as."""
    folders: dict[Path, str] = {}
    for package, folder in PACKAGE_DIR.items():
        root = ROOT / folder
        for path in [root, *root.rglob("*")]:
            if path.is_dir() and not SKIPPED_DIRS & set(path.relative_to(ROOT).parts):
                folders[path] = ".".join([package, *path.relative_to(root).parts])
    return folders


def _python_files() -> list[Path]:
    files = []
    for folder, dirs, names in os.walk(ROOT):
        dirs[:] = [d for d in dirs if d not in SKIPPED_DIRS | {"vendor"}]  # prune .venv early
        files += [Path(folder) / n for n in names if n.endswith(".py")]
    return files


def test_the_layers_are_the_known_ones() -> None:
    # a guard on the guard: if the mapping were read wrongly, the tests below would check nothing
    known = {"geometry", "protocol", "agent", "calibration", "fusion", "recording", "server"}
    assert known <= LAYERS
    assert PACKAGE_DIR["skelfuse"] == "skelfuse"


def test_every_package_folder_is_listed_for_setuptools() -> None:
    listed = set(SETUPTOOLS["packages"])
    missing = {
        name: str(path.relative_to(ROOT))
        for path, name in _package_folders().items()
        if name not in listed
    }
    assert not missing, f"add to [tool.setuptools] packages in pyproject.toml: {missing}"


def test_every_listed_package_has_its_folder() -> None:
    stale = [p for p in SETUPTOOLS["packages"] if not _folder_of(p).is_dir()]
    assert not stale, f"listed in pyproject.toml but no such folder: {stale}"


def test_every_top_level_package_folder_is_mapped() -> None:
    mapped = {Path(folder).parts[0] for folder in PACKAGE_DIR.values()}
    unmapped = sorted(
        path.parent.name
        for path in ROOT.glob("*/__init__.py")
        if path.parent.name not in mapped | NOT_SHIPPED
    )
    assert not unmapped, f"add to [tool.setuptools.package-dir] in pyproject.toml: {unmapped}"


def test_files_in_data_folders_are_shipped() -> None:
    package_data: dict[str, list[str]] = SETUPTOOLS.get("package-data", {})
    unshipped = []
    for path, name in _package_folders().items():
        if (path / "__init__.py").exists():
            continue  # a code package: setuptools ships its .py files
        patterns = package_data.get(name, [])
        for file in path.iterdir():
            if file.is_file() and not any(fnmatch.fnmatch(file.name, p) for p in patterns):
                unshipped.append(str(file.relative_to(ROOT)))
    assert not unshipped, f"not matched by [tool.setuptools.package-data]: {unshipped}"


def _bare_layer_imports(source: str) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found += [(node.lineno, n) for n in names if n.split(".")[0] in LAYERS]
    return found


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("import server", ["server"]),
        ("from protocol.wire import encode", ["protocol.wire"]),
        ("import os, fusion.hub as hub", ["fusion.hub"]),
        ("from skelfuse.server import app", []),
        ("from . import server", []),
        ("import serverless", []),
    ],
)
def test_the_import_scan_sees_bare_layer_names(source: str, expected: list[str]) -> None:
    assert [name for _, name in _bare_layer_imports(source)] == expected


def test_no_source_imports_a_layer_by_its_bare_name() -> None:
    files = _python_files()
    assert len(files) > 50  # the scan found the tree
    offenders = [
        f"{path.relative_to(ROOT)}:{line}: {name}"
        for path in files
        for line, name in _bare_layer_imports(path.read_text(encoding="utf-8"))
    ]
    assert not offenders, "import these as skelfuse.<layer>...:\n" + "\n".join(offenders)


def test_fusion_declares_what_it_needs_so_the_resolver_refuses_the_mono_mix() -> None:
    """numpy 2 and numba wherever fusion runs (the server includes the fusion extra), numpy<2 in
    the mono extra: pip then refuses ``[server,mono]`` with a conflict instead of installing a
    fusion that fails on numpy 1's missing functions."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras: dict[str, list[str]] = project["optional-dependencies"]
    assert {"numpy>=2", "numba>=0.60"} <= set(extras["fusion"])
    assert "skelfuse[fusion]" in extras["server"]
    assert "numpy>=1.26,<2" in extras["mono"]


def test_fusion_refuses_to_import_without_numba_or_numpy_2(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import numpy as np

    from skelfuse import jit

    jit.require_fusion_dependencies()  # this environment has both
    monkeypatch.setitem(jit._found, "numba", None)
    with pytest.raises(ImportError, match=r"numba \(not installed\).*skelfuse\[fusion\]"):
        jit.require_fusion_dependencies()
    monkeypatch.undo()
    monkeypatch.setattr(np, "__version__", "1.26.4")
    with pytest.raises(ImportError, match=r"numpy 2 \(this environment has numpy 1\.26\.4\)"):
        jit.require_fusion_dependencies()
