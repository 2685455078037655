"""The API's documentation pages, offline: Swagger UI at ``/docs`` and ReDoc at ``/redoc``.

Their assets (Swagger UI 5 and ReDoc 2, as built for browsers) come from the ``fastapi-offline``
distribution and are served at ``/docs/assets``: the pages load nothing from another site, so
they work on a machine without internet. The pages run under the same CSP as the other pages
(scripts from this site only): Swagger UI is started by ``/static/docs.js`` (not an inline
script, which the CSP forbids), which reads the document's URL from the page; ReDoc starts
itself from its ``<redoc spec-url>`` element. ReDoc makes its styles at run time, ``<style>``
elements (styled-components, and a stylesheet injected as the bundle loads, before any option
could give it a nonce), and runs its search in a worker made from a ``blob:`` URL: its page's CSP
allows inline styles and such workers, scripts stay this site's only. ReDoc 2 shows the Redocly
logo from Redocly's CDN at the foot of its menu: the CSP blocks it (nothing is fetched) and ReDoc
drops the image."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

from service.html import env
from service.infra.security import page_csp

router = APIRouter(include_in_schema=False)

ASSETS_URL = "/docs/assets"


def assets() -> StaticFiles:
    """The Swagger UI and ReDoc bundles of the fastapi-offline distribution."""
    return StaticFiles(packages=[("fastapi_offline", "static")])


def _page(template: str, request: Request, inline_styles: bool = False) -> HTMLResponse:
    root = request.scope.get("root_path", "")
    app = request.app
    html = (
        env()
        .get_template(template)
        .render(title=app.title, openapi_url=f"{root}{app.openapi_url}", assets=f"{root}{ASSETS_URL}", root=root)
    )
    return HTMLResponse(html, headers={"Content-Security-Policy": page_csp(inline_styles)})


@router.get("/docs")
def swagger_ui(request: Request) -> HTMLResponse:
    return _page("docs.html", request)


@router.get("/redoc")
def redoc(request: Request) -> HTMLResponse:
    return _page("redoc.html", request, inline_styles=True)
