"""``/docs``: Swagger UI from the installed package, so the REST reference works offline.

FastAPI's own ``/docs`` loads Swagger UI from a CDN: on a show network or a lab PC without
internet the page stayed blank (issue 13). The ``swagger-ui-bundle-v2`` wheel (Apache-2.0, the
upstream ``swagger-ui-dist`` files as a Python package) ships them; they are served under
:data:`ASSETS` and the page is FastAPI's ``get_swagger_ui_html`` pointed at them. ReDoc (also a
CDN script) is turned off: one reference is enough.

With a token, "Authorize" takes it once and "Try it out" sends it as ``Authorization: Bearer``
on the operations the OpenAPI document marks (``server/openapi.py``).
"""

from __future__ import annotations

import logging
from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

try:  # in the server extras; without it (an old install), FastAPI's CDN page stays
    from swagger_ui_bundle import swagger_ui_path  # type: ignore[import-untyped]
except ImportError:  # pragma: no cover - the tests run with the extras
    swagger_ui_path = None

logger = logging.getLogger(__name__)
DOCS_URL = "/docs"
ASSETS = "/docs-assets"
"""Where Swagger UI's files are served (a sibling of ``/docs``: a mount below ``/docs`` would
take ``/docs`` itself)."""
SWAGGER_UI_DIR = None if swagger_ui_path is None else Path(str(swagger_ui_path))


def install(app: FastAPI) -> None:
    """Replace FastAPI's CDN pages (``/docs``, its OAuth2 redirect, ``/redoc``) with ``/docs``
    and its assets from the package.

    Without the package (installed before it was a dependency) FastAPI's page stays, with a
    warning: it works where the CDN can be reached.

    Raises:
        RuntimeError: the package's files are missing (a broken install).
    """
    if SWAGGER_UI_DIR is None:
        logger.warning("/docs needs internet: pip install 'skelfuse[server]' to serve it offline")
        return
    if not (SWAGGER_UI_DIR / "swagger-ui-bundle.js").is_file():
        raise RuntimeError(f"Swagger UI's files are missing from {SWAGGER_UI_DIR}")
    cdn_pages = {app.docs_url, app.swagger_ui_oauth2_redirect_url, app.redoc_url} - {None}
    app.router.routes[:] = [
        route for route in app.router.routes if getattr(route, "path", None) not in cdn_pages
    ]
    app.docs_url = app.redoc_url = app.swagger_ui_oauth2_redirect_url = None
    app.mount(ASSETS, StaticFiles(directory=SWAGGER_UI_DIR), name="swagger-ui")
    title = f"{app.title} - REST reference"

    @app.get(DOCS_URL, include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=title,
            swagger_js_url=f"{ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS}/favicon-32x32.png",
            oauth2_redirect_url=None,
        )
