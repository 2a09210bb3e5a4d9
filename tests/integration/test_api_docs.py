"""``/docs`` offline, with the token (issue 13 item 6): Swagger UI's files come from the server
itself, and "Authorize" + "Try it out" reach an operation that needs the token.

Before: FastAPI's page loaded Swagger UI from a CDN (blank without internet), and the OpenAPI
document had no way to send the token, so "Try it out" got 401.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from html.parser import HTMLParser
from urllib.parse import urljoin

import httpx
import pytest

from tests.integration.conftest import LiveServer
from tests.support_browser import offline_page

TOKEN = "docs-test-token"


class _AssetUrls(HTMLParser):
    """Every URL a page loads by itself: scripts, stylesheets, icons, images."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if tag in ("script", "img") and values.get("src"):
            self.urls.append(str(values["src"]))
        if tag == "link" and values.get("href"):
            self.urls.append(str(values["href"]))


@pytest.fixture
def server(server_factory: Callable[..., LiveServer]) -> LiveServer:
    return server_factory(api_token=TOKEN)


def test_docs_assets_are_all_served_by_the_server(server: LiveServer) -> None:
    page = httpx.get(server.http_url + "/docs")
    assert page.status_code == 200
    parser = _AssetUrls()
    parser.feed(page.text)
    assert len(parser.urls) >= 3, parser.urls  # Swagger UI's script, stylesheet and icon
    for url in parser.urls:
        absolute = urljoin(server.http_url + "/docs", url)
        assert absolute.startswith(server.http_url + "/"), f"{url} is not on this server"
        answer = httpx.get(absolute)
        assert answer.status_code == 200, (url, answer.status_code)
        assert len(answer.content) > 0
    # The script the page starts Swagger UI with names the OpenAPI document on this server.
    assert re.search(r"url: '/openapi\.json'", page.text), page.text
    # FastAPI's other CDN page is gone rather than left blank.
    assert httpx.get(server.http_url + "/redoc").status_code == 404
    schemes = httpx.get(server.http_url + "/openapi.json").json()["components"]["securitySchemes"]
    assert schemes["bearer"] == {**schemes["bearer"], "type": "http", "scheme": "bearer"}


@pytest.mark.browser
@pytest.mark.timeout(120)
def test_swagger_ui_renders_offline_and_try_it_out_sends_the_token(server: LiveServer) -> None:
    with offline_page() as offline:
        page = offline.page
        page.goto(server.http_url + "/docs", wait_until="load")
        operation = page.locator("#operations-status-persons_api_persons_get")
        operation.wait_for(state="visible", timeout=30_000)  # the operations list rendered
        assert page.locator(".opblock").count() >= 20
        assert offline.refused == [], f"the page tried to leave this machine: {offline.refused}"

        operation.locator(".opblock-summary").first.click()  # unfold GET /api/persons
        operation.locator(".try-out__btn").click()

        def try_persons() -> str:
            """Execute GET /api/persons from its panel; the status Swagger UI shows."""
            clear = operation.locator("button.btn-clear")
            if clear.count():
                clear.click()  # the previous answer, so the one read below is new
            operation.locator("button.execute").click()
            status = operation.locator(".live-responses-table .response .response-col_status")
            status.first.wait_for(state="visible")
            return status.first.inner_text().strip()

        # Without the token the server refuses: the page really calls it.
        assert try_persons().startswith("401")
        page.locator(".auth-wrapper .authorize").click()
        dialog = page.locator(".modal-ux")
        dialog.locator("input").first.fill(TOKEN)
        dialog.locator("button.authorize").click()
        dialog.locator("button.btn-done").click()
        assert try_persons().startswith("200")
        assert offline.page_errors == []
        assert offline.refused == []
