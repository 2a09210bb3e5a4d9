"""REST fuzzing with schemathesis against the live server's own OpenAPI (``/openapi.json``).

Every operation gets generated requests, valid ones (``positive``) and invalid ones
(``negative``), up to :data:`EXAMPLES` each; every response must not be a 5xx
(``not_a_server_error``) and must match the schema where the schema declares that status code
(``response_schema_conformance``). Undeclared codes (e.g. a 404 for an unknown run id) are not
failures here. All failures are collected and reported together, each with the curl command that
reproduces it and the server-side errors logged meanwhile.
"""

from __future__ import annotations

import logging
from typing import Any

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error, response_schema_conformance

from tests.integration.conftest import LiveServer

EXAMPLES = 30
"""Generated requests per operation and generation mode (23 operations: about 1 400 requests)."""

CHECKS = [not_a_server_error, response_schema_conformance]


def fuzz(operation: Any, mode: GenerationMode, base_url: str) -> str | None:
    """Run one operation in one generation mode: None, or its first failure (with a curl)."""

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        database=None,
        phases=[Phase.explicit, Phase.generate],  # no shrinking: report the first failure
        suppress_health_check=list(HealthCheck),
    )
    @given(case=operation.as_strategy(generation_mode=mode))
    def run(case: Any) -> None:
        response = case.call(base_url=base_url, timeout=10)
        case.validate_response(response, checks=CHECKS)  # its error carries a curl command

    try:
        run()
    except Unsatisfiable:  # nothing invalid to send (no parameters, or any string is valid)
        return None
    except (Exception, BaseExceptionGroup) as exc:  # schemathesis' FailureGroup included
        return f"{operation.label} [{mode.value}]: {exc}"
    return None


def test_every_operation_answers_without_5xx_and_as_documented(
    live_server: LiveServer, caplog: pytest.LogCaptureFixture
) -> None:
    schema = schemathesis.openapi.from_url(live_server.http_url + "/openapi.json", timeout=10)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 20, [op.label for op in operations]
    caplog.set_level(logging.ERROR)
    failures: list[str] = []
    for operation in operations:
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            caplog.clear()
            failure = fuzz(operation, mode, live_server.http_url)
            if failure is not None:
                failures.append(f"{failure}\n  server log (errors):\n{caplog.text}")
    assert not failures, f"{len(failures)} failing operation(s):\n\n" + "\n\n".join(failures)
