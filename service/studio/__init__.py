"""The studio: a browser page at ``/`` (upload, jobs, results) and offline API docs.

Plain HTML, CSS and ES modules under ``static/``, served as files: no build step, no CDN.
The page talks only to the public API (``/v1``) with the tab's API key as a bearer token,
so it sees exactly what that key's tenant may see. ``/docs`` (Swagger UI) and ``/redoc``
serve the assets shipped in the ``fastapi-offline`` package instead of FastAPI's CDN pages.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

STATIC = Path(__file__).with_name("static")
INDEX = STATIC / "index.html"
PAGE_HEADERS = {
    "Cache-Control": "no-cache",
    # Only the server's own scripts and API: an injected <script> or form target has nowhere
    # to go. Inline style attributes are used for the legend swatches.
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data: blob:; "
                               "style-src 'self' 'unsafe-inline'; object-src 'none'; "
                               "base-uri 'none'; frame-ancestors 'none'; form-action 'self'",
    "X-Content-Type-Options": "nosniff",
}

router = APIRouter(include_in_schema=False)


@router.get("/")
async def studio_page() -> FileResponse:
    """The studio's single page."""
    return FileResponse(INDEX, media_type="text/html", headers=PAGE_HEADERS)


@router.get("/jobs/{job_id}")
async def studio_job_page(job_id: str) -> FileResponse:
    """A deep link to a job's result: the same page, which reads the id from its URL."""
    return FileResponse(INDEX, media_type="text/html", headers=PAGE_HEADERS)


def docs_assets() -> Path:
    """Swagger UI 5 and ReDoc files shipped by ``fastapi-offline`` (OpenAPI 3.1 capable)."""
    return Path(str(files("fastapi_offline") / "static"))


@router.get("/docs")
async def api_docs() -> HTMLResponse:
    """Swagger UI with local assets: works offline and in the container."""
    return get_swagger_ui_html(
        openapi_url="/openapi.json", title="bonefit API",
        swagger_js_url="/static/docs/swagger-ui-bundle.js",
        swagger_css_url="/static/docs/swagger-ui.css",
        swagger_favicon_url="/static/docs/favicon.png")


@router.get("/redoc")
async def api_redoc() -> HTMLResponse:
    """ReDoc with local assets."""
    return get_redoc_html(openapi_url="/openapi.json", title="bonefit API",
                          redoc_js_url="/static/docs/redoc.standalone.js",
                          redoc_favicon_url="/static/docs/favicon.png", with_google_fonts=False)


def install(app: FastAPI) -> None:
    """Serve the studio, its static files and the offline docs on ``app`` (created with
    ``docs_url=None, redoc_url=None``)."""
    app.mount("/static/docs", StaticFiles(directory=docs_assets()), name="api-docs")
    app.mount("/static", StaticFiles(directory=STATIC), name="studio")
    app.include_router(router)
