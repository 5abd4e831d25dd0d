"""A browser's page request that fails gets an HTML page with the console's links, not raw JSON."""

from __future__ import annotations

import html

import httpx

HTML = {"Accept": "text/html,application/xhtml+xml"}


def test_page_errors_are_html_pages_and_the_api_keeps_json(tmp_path, serve_console):
    with serve_console(tmp_path, seed_numba=False) as console:
        missing = console.admin.get("/models/no-such-model", headers=HTML)
        assert missing.status_code == 404 and missing.headers["content-type"].startswith("text/html")
        assert "no model named 'no-such-model'" in html.unescape(missing.text) and 'href="/create"' in missing.text
        assert "{" not in missing.text.split("<main>")[1]  # no JSON in the page
        api = console.admin.get("/api/models/no-such-model", headers=HTML)
        assert api.status_code == 404 and api.json()["detail"]
        with httpx.Client(base_url=console.url) as anonymous:
            page = anonymous.get("/create", headers=HTML)
            assert page.status_code == 303 and page.headers["location"] == "/login"
            assert anonymous.get("/api/models", headers=HTML).status_code == 401
