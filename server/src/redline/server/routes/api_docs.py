"""The interactive API page, ``/docs``: Swagger UI 5 from files Redline serves itself (the
``swagger-ui-bundle-v2`` package), as it serves plotly.js. FastAPI's own page loads Swagger UI
from a CDN, and a lab without the internet saw a blank page (a new user's trial, 2026-12-06);
Swagger UI 4 cannot render the OpenAPI 3.1 document FastAPI makes."""

from __future__ import annotations

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles
from swagger_ui_bundle import swagger_ui_path  # type: ignore[import-untyped]

#: where the Swagger UI files are served
ASSETS = "/static-swagger"

router = APIRouter(include_in_schema=False)


@router.get("/docs")
def api_docs(request: Request) -> HTMLResponse:
    app = request.app
    return get_swagger_ui_html(
        openapi_url=app.openapi_url or "/openapi.json",
        title=f"{app.title}: API",
        swagger_js_url=f"{ASSETS}/swagger-ui-bundle.js",
        swagger_css_url=f"{ASSETS}/swagger-ui.css",
        swagger_favicon_url=f"{ASSETS}/favicon-32x32.png",
    )


def mount(app: FastAPI) -> None:
    """``/docs`` and the files it loads (the app is made with ``docs_url=None``)."""
    app.mount(ASSETS, StaticFiles(directory=swagger_ui_path), name="swagger")
    app.include_router(router)
