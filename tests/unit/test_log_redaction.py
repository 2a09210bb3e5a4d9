"""Secrets are masked in log records before any handler writes them (issue 12)."""

from __future__ import annotations

import logging

import pytest

from skelfuse.server.log_redaction import RedactSecrets, redact, redact_uvicorn_logs

TOKEN = "-Zx9_secret-TOKEN~"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (f"/ws/skeletons?token={TOKEN}", "/ws/skeletons?token=***"),
        (f"/ws?format=json&token={TOKEN}&raw=1", "/ws?format=json&token=***&raw=1"),
        (f'"GET /?TOKEN={TOKEN} HTTP/1.1" 200', '"GET /?TOKEN=*** HTTP/1.1" 200'),
        (f"/x?access_token={TOKEN}#top", "/x?access_token=***#top"),
        (f"/x?api_key={TOKEN}&secret={TOKEN}", "/x?api_key=***&secret=***"),
        (f"/x?token%3D{TOKEN}", "/x?token%3D***"),
        (f"Authorization: Bearer {TOKEN}", "Authorization: Bearer ***"),
        (f"(b'authorization', b'Bearer {TOKEN}')", "(b'authorization', b'Bearer ***')"),
        ("/api/persons?tokens_left=3&monkey=1", "/api/persons?tokens_left=3&monkey=1"),
        ("no secrets here", "no secrets here"),
        ("a Bearer token; ?token= then it", "a Bearer token; ?token= then it"),
    ],
)  # fmt: skip
def test_secret_values_are_masked_and_nothing_else(text: str, expected: str) -> None:
    assert redact(text) == expected


def test_an_access_line_is_written_without_the_token(caplog: pytest.LogCaptureFixture) -> None:
    logger = logging.getLogger("test.redaction.access")
    logger.addFilter(RedactSecrets())
    caplog.set_level(logging.INFO, logger=logger.name)
    # uvicorn's access record: the path with its query string is one of the arguments.
    logger.info(
        '%s - "%s %s HTTP/%s" %d', "127.0.0.1:5", "GET", f"/ws/skeletons?token={TOKEN}", "1.1", 101
    )
    logger.info("header %r", [(b"authorization", f"Bearer {TOKEN}".encode())])
    logger.info("%(path)s", {"path": f"/x?token={TOKEN}"})
    assert TOKEN not in caplog.text
    assert caplog.text.count("token=***") == 2
    assert "Bearer ***" in caplog.text
    assert caplog.records[0].args[4] == 101  # type: ignore[index]  # the rest untouched


def test_a_secret_in_the_format_string_keeps_the_record_formattable(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Masking ``token=%s`` in the format string alone would eat the placeholder: the record
    could not be formatted any more ("not all arguments converted"), and the line was lost."""
    logger = logging.getLogger("test.redaction.format")
    logger.addFilter(RedactSecrets())
    caplog.set_level(logging.INFO, logger=logger.name)
    logger.info("open %s/?token=%s (docs at %s)", "http://lab:8000", TOKEN, "http://lab:8000/docs")
    logger.info("open %s/?token=<%s>", "http://lab:8000", "your --token")
    logger.info("Authorization: Bearer %s sent to %d sensors", TOKEN, 3)
    assert [r.getMessage() for r in caplog.records] == [
        "open http://lab:8000/?token=*** (docs at http://lab:8000/docs)",
        "open http://lab:8000/?token=*** --token>",
        "Authorization: Bearer *** sent to 3 sensors",
    ]


def test_uvicorn_loggers_get_one_filter_each() -> None:
    redact_uvicorn_logs()
    redact_uvicorn_logs()
    for name in ("uvicorn.access", "uvicorn.error"):
        filters = logging.getLogger(name).filters
        assert sum(isinstance(f, RedactSecrets) for f in filters) == 1, name
