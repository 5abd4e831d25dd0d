"""Errors of the console's HTML pages as HTML pages with navigation (the JSON API keeps JSON):
a page opened without a session goes to the sign-in page; any other refusal says what happened in a
page with the console's links, never raw JSON and never a server path."""

from __future__ import annotations

from fastapi import Request
from fastapi.responses import RedirectResponse, Response

from laplab.console.outcomes import without_paths

TITLES = {400: "That request cannot be done", 401: "Sign in first", 403: "Not allowed", 404: "Not found",
          405: "Not possible here", 409: "Not now", 413: "Too large", 429: "Too many attempts"}
NOT_PAGES = ("/api/", "/static/", "/openapi.json", "/docs", "/redoc")


def wants_html(request: Request) -> bool:
    """Whether the request is a browser's for a page (not the API, a file or a script's request)."""
    path = request.url.path
    if path.startswith(NOT_PAGES):
        return False
    return "text/html" in request.headers.get("accept", "")


def error_page(request: Request, status: int, detail) -> Response:
    """The HTML answer to an HTTP error of a page."""
    if status == 401:
        return RedirectResponse("/login", status_code=303)
    from laplab.console.pages import TEMPLATES
    message = detail.get("message") if isinstance(detail, dict) else detail
    title = TITLES.get(status, "Something went wrong")
    return TEMPLATES.TemplateResponse(request, "error.html", {
        "title": title, "status": status, "message": without_paths(str(message or title)),
        "next_href": "/", "next_label": "Back to your models"}, status_code=status)
