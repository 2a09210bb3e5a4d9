"""docker-compose.yml and the Dockerfile stay in step with the code (no Docker engine here)."""

from __future__ import annotations

from pathlib import Path

import yaml

from skelfuse.cli import build_parser, parse_pose
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
    dockerfile = (ROOT / "Dockerfile").read_text()
    for package in ("protocol", "agent", "calibration", "server", "skelfuse"):
        assert f"COPY {package} ./{package}" in dockerfile
