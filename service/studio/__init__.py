"""The studio: a browser page at ``/`` (upload, jobs, results) and offline API docs.

Plain HTML, CSS and ES modules under ``static/``, served as files: no build step, no CDN.
The page talks only to the public API (``/v1``) with the tab's API key as a bearer token,
so it sees exactly what that key's tenant may see. ``/docs`` serves Swagger UI from the
``swagger-ui-bundle`` package's assets instead of FastAPI's CDN page.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

STATIC = Path(__file__).with_name("static")
INDEX = STATIC / "index.html"
NO_CACHE = {"Cache-Control": "no-cache"}

router = APIRouter(include_in_schema=False)


@router.get("/")
async def studio_page() -> FileResponse:
    """The studio's single page."""
    return FileResponse(INDEX, media_type="text/html", headers=NO_CACHE)


@router.get("/jobs/{job_id}")
async def studio_job_page(job_id: str) -> FileResponse:
    """A deep link to a job's result: the same page, which reads the id from its URL."""
    return FileResponse(INDEX, media_type="text/html", headers=NO_CACHE)


def swagger_assets() -> Path:
    """The Swagger UI files shipped by ``swagger-ui-bundle``."""
    from swagger_ui_bundle import swagger_ui_path

    return Path(swagger_ui_path)


@router.get("/docs")
async def api_docs() -> HTMLResponse:
    """Swagger UI with local assets: works offline and in the container."""
    return get_swagger_ui_html(
        openapi_url="/openapi.json", title="bonefit API",
        swagger_js_url="/static/swagger/swagger-ui-bundle.js",
        swagger_css_url="/static/swagger/swagger-ui.css",
        swagger_favicon_url="/static/swagger/favicon-32x32.png")


def install(app: FastAPI) -> None:
    """Serve the studio, its static files and the offline docs on ``app`` (created with
    ``docs_url=None, redoc_url=None``)."""
    app.mount("/static/swagger", StaticFiles(directory=swagger_assets()), name="swagger")
    app.mount("/static", StaticFiles(directory=STATIC), name="studio")
    app.include_router(router)
