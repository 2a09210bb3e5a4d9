"""REST fuzzing with schemathesis against a live server's own OpenAPI (``/openapi.json``).

The server runs with a token, as a deployment does, and the fuzzer sends it. Every operation gets
generated requests, valid ones (``positive``) and invalid ones (``negative``), up to
:data:`EXAMPLES` each, and every response must:

- not be a 5xx (``not_a_server_error``);
- have a status the document lists for that operation (``status_code_conformance``; issue 12:
  13 operations answered 4xx codes it did not list), with the declared content type and schema;
- be accepted when the request is schema-valid (``positive_data_acceptance``: 2xx, or 404/409
  for the server's state; issue 12: 3 schema-valid requests were refused), and refused when it
  is not (``negative_data_rejection``);
- need the token where the document says so (``ignored_auth``).

``schemathesis.toml`` holds the one exception (an import whose matrices are not rigid: JSON
Schema cannot say so). All failures are collected and reported together, each with the curl
command that reproduces it and the server-side errors logged meanwhile.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import (
    content_type_conformance,
    ignored_auth,
    negative_data_rejection,
    not_a_server_error,
    positive_data_acceptance,
    response_schema_conformance,
    status_code_conformance,
)
from schemathesis.config import SchemathesisConfig

from tests.conftest import PROJECT_ROOT
from tests.integration.conftest import LiveServer

pytestmark = pytest.mark.timeout(600)
TOKEN = "fuzz-token"
EXAMPLES = 25
"""Generated requests per operation and generation mode (24 operations: about 1 200 requests)."""

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    positive_data_acceptance,
    negative_data_rejection,
    ignored_auth,
]


def fuzz(operation: Any, mode: GenerationMode, base_url: str) -> str | None:
    """Run one operation in one generation mode: None, or its first failure (with a curl)."""
    # An explicit check list overrides schemathesis.toml's per-operation `enabled = false`
    # (validate_response runs every check it is given), so the list is filtered here.
    checks_config = operation.schema.config.checks_config_for(operation=operation)
    checks = [c for c in CHECKS if checks_config.get_by_name(name=c.__name__).enabled]

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        database=None,
        phases=[Phase.explicit, Phase.generate],  # no shrinking: report the first failure
        suppress_health_check=list(HealthCheck),
    )
    @given(case=operation.as_strategy(generation_mode=mode))
    def run(case: Any) -> None:
        headers = {"Authorization": f"Bearer {TOKEN}"}
        response = case.call(base_url=base_url, headers=headers, timeout=10)
        case.validate_response(response, checks=checks, headers=headers)

    try:
        run()
    except Unsatisfiable:  # nothing invalid to send (no parameters, or any string is valid)
        return None
    except (Exception, BaseExceptionGroup) as exc:  # schemathesis' FailureGroup included
        return f"{operation.label} [{mode.value}]: {exc}"
    return None


def test_every_operation_answers_as_documented_without_5xx(
    server_factory: Callable[..., LiveServer], caplog: pytest.LogCaptureFixture
) -> None:
    live = server_factory(api_token=TOKEN)
    config = SchemathesisConfig.from_path(PROJECT_ROOT / "schemathesis.toml")
    schema = schemathesis.openapi.from_url(live.http_url + "/openapi.json", config=config)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 20, [op.label for op in operations]
    caplog.set_level(logging.ERROR)
    failures: list[str] = []
    for operation in operations:
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            caplog.clear()
            failure = fuzz(operation, mode, live.http_url)
            if failure is not None:
                failures.append(f"{failure}\n  server log (errors):\n{caplog.text}")
    assert not failures, f"{len(failures)} failing operation(s):\n\n" + "\n\n".join(failures)
