"""Headless Debian Chromium through Playwright, with every request off this machine refused.

For browser tests outside the viewer's own module (``/docs`` offline, the demo's printed
address). They skip with a reason when Chromium or playwright is missing, and fail under CI
(env ``CI``), like ``tests/e2e/test_viewer_browser.py``.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from tests.support import unavailable

if TYPE_CHECKING:
    from playwright.sync_api import Page, Route

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--use-gl=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
LOOPBACK = frozenset({"127.0.0.1", "localhost", "[::1]", "::1"})


def chromium_executable() -> str:
    """Debian's Chromium; skips (fails under CI) when absent."""
    if Path("/usr/bin/chromium").is_file():
        return "/usr/bin/chromium"
    found = shutil.which("chromium")
    if found is None:
        unavailable(
            "Chromium not found (/usr/bin/chromium or `chromium` on PATH)",
            "CI must install Debian's `chromium` package (apt-get install chromium)",
        )
    return found


class OfflinePage:
    """A page whose requests to anything but loopback fail, as on a machine without internet;
    the refused URLs are kept in :attr:`refused`."""

    def __init__(self, page: Page) -> None:
        self.page = page
        self.refused: list[str] = []
        self.page_errors: list[str] = []
        page.on("pageerror", lambda exc: self.page_errors.append(str(exc)))
        page.route("**/*", self._route)

    def _route(self, route: Route) -> None:
        url = route.request.url
        host = urlsplit(url).hostname or ""
        if url.startswith(("data:", "blob:")) or host in LOOPBACK or f"[{host}]" in LOOPBACK:
            route.continue_()
        else:
            self.refused.append(url)
            route.abort("internetdisconnected")


@contextmanager
def offline_page(width: int = 1280, height: int = 800) -> Iterator[OfflinePage]:
    """A fresh headless Chromium page with no network beyond loopback."""
    executable = chromium_executable()
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        unavailable(
            "the playwright Python package is not installed",
            "CI must install the dev extras (pip install -e '.[dev]')",
        )
    with sync_playwright() as manager:
        browser = manager.chromium.launch(
            executable_path=executable, args=CHROMIUM_ARGS, headless=True, timeout=30_000
        )
        try:
            context = browser.new_context(viewport={"width": width, "height": height})
            page = context.new_page()
            page.set_default_timeout(15_000)
            yield OfflinePage(page)
        finally:
            browser.close()
