"""The OpenAPI document lists every status an operation can answer (issue 12: 13 did not).

Each route declares the domain errors it raises (``responses=error_responses(...)``,
``server/errors.py``). What whole kinds of operations can answer, whatever the route, comes from
the middleware and FastAPI and is added here, from the same rules that produce it:

- **401** and ``security: bearer`` where :func:`skelfuse.server.security.needs_token` says the
  token is needed, when the server has one (without a token nothing is refused, and the
  document says so by not asking for it);
- **413** (``server/body_limit.py``) and **400** (a body that is not JSON text, which FastAPI
  refuses before validation) on every operation that takes a body;
- **422** FastAPI declares itself, on operations with parameters or a body.

:func:`install` also serves the document's pages: ``/docs`` offline (``server/api_docs.py``).
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI

from skelfuse.server import api_docs
from skelfuse.server.errors import ErrorBody
from skelfuse.server.security import needs_token

BEARER_SCHEME = "bearer"


def document_common_errors(
    schema: dict[str, Any], token_required: bool, max_body_bytes: int
) -> None:
    """Add the statuses every operation of a kind can answer to ``schema`` (in place).

    Args:
        schema: an OpenAPI 3 document as FastAPI generates it.
        token_required: the server was started with an API token.
        max_body_bytes: the body size limit (``Settings.max_body_bytes``).
    """
    components = schema.setdefault("components", {})
    components.setdefault("schemas", {}).setdefault(
        ErrorBody.__name__, ErrorBody.model_json_schema()
    )
    if token_required:
        components.setdefault("securitySchemes", {})[BEARER_SCHEME] = {
            "type": "http",
            "scheme": "bearer",
            "description": "the server's --token (or SKELFUSE_TOKEN); docs/security.md",
        }
    for path, item in schema.get("paths", {}).items():
        for method, operation in item.items():
            if not isinstance(operation, dict) or "responses" not in operation:
                continue  # "parameters" and other path-level keys
            responses = operation["responses"]
            if token_required and needs_token(method, path):
                operation["security"] = [{BEARER_SCHEME: []}]
                _add(responses, 401, "Missing or wrong token (send 'Authorization: Bearer …').")
            if "requestBody" in operation:
                _add(responses, 413, f"The request body is over {max_body_bytes} bytes.")
                _add(responses, 400, "The request body is not JSON text (UTF-8).")


def _add(responses: dict[str, Any], status: int, description: str) -> None:
    entry = responses.get(str(status))
    if entry is not None:
        if description not in entry["description"]:
            entry["description"] += f" Or: {description}"
        return
    responses[str(status)] = {
        "description": description,
        "content": {
            "application/json": {"schema": {"$ref": f"#/components/schemas/{ErrorBody.__name__}"}}
        },
    }


def install(app: FastAPI, token_required: bool, max_body_bytes: int) -> None:
    """Make ``app``'s ``/openapi.json`` carry the common errors (generated once, on first use),
    and serve ``/docs`` from the installed Swagger UI instead of a CDN (:mod:`api_docs`).

    Raises:
        RuntimeError: Swagger UI's files are missing (a broken install).
    """
    generate = app.openapi
    completed: list[dict[str, Any]] = []

    def openapi() -> dict[str, Any]:
        if not completed:
            schema = generate()
            document_common_errors(schema, token_required, max_body_bytes)
            completed.append(schema)
        return completed[0]

    app.openapi = openapi  # type: ignore[method-assign]
    api_docs.install(app)
