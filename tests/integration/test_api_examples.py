"""The Python examples of docs/api.md ("Python client") run as written, against a real uvicorn
server with a token and a simulated agent, each in its own interpreter."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.integration.conftest import AgentThread, LiveServer

pytestmark = pytest.mark.timeout(120)
API_MD = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def _doc_examples() -> list[str]:
    """The Python blocks of docs/api.md's "Python client" section."""
    text = API_MD.read_text()
    section = text.split("### Python client", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, flags=re.DOTALL)


@pytest.mark.parametrize("index", [0, 1])
def test_the_python_examples_in_api_md_run(
    index: int, server_factory: Callable[..., LiveServer],
    agent_factory: Callable[..., AgentThread],
) -> None:  # fmt: skip
    examples = _doc_examples()
    assert len(examples) == 2
    live = server_factory(api_token="doc-token")
    agent_factory(live.zmq_url, "cam-a")
    env = {**os.environ, "SKELFUSE_URL": live.http_url, "SKELFUSE_TOKEN": "doc-token"}
    run = subprocess.run([sys.executable, "-c", examples[index]], env=env, capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    assert run.returncode == 0, run.stderr
    lines = run.stdout.strip().splitlines()
    assert len(lines) >= 10, run.stdout
