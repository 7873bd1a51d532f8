"""The view's page in a real browser (headless Debian chromium through Playwright), fast: the server
in-process with a fake follower (``tests.viewfake``), no flight. A drone may be named anything the
fleet allows (``constructor``, ``__proto__``: names are data, never an object's properties); any error
of the page's own shows it not live, every row stale."""

from __future__ import annotations

import os
from typing import Any

import pytest

from tests.integration.test_view import ARGS, CHROMIUM, REPO
from tests.viewfake import FakeFollower, row, serving

pytestmark = [pytest.mark.xdist_group("view")]

NAMES = ["d1", "constructor", "__proto__", "toString", "hasOwnProperty"]


@pytest.fixture()
def page_errors(tmp_path) -> Any:
    """A fresh page and the errors it raised (``pageerror``)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"no chromium (the browser test); to run it: sudo make -C {REPO} browser")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            yield page, errors
        finally:
            browser.close()


def _rows(page: Any) -> list[tuple[str, str, str]]:
    return page.evaluate("""() => Array.from(document.querySelectorAll('#rows tr')).map(
        (tr) => [tr.dataset.drone, tr.dataset.owner, tr.dataset.stale])""")


def test_drones_named_like_object_properties_render_and_stay_consistent(page_errors):
    """Found: a drone named ``constructor`` or ``__proto__`` broke the page."""
    page, errors = page_errors
    follower = FakeFollower([row(n, position=[47.0 + i / 1000, 8.0, 30.0]) for i, n in enumerate(NAMES)])
    with serving(follower) as port:
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_selector("#conn[data-state=live]", timeout=10_000)
        for n in NAMES:
            page.wait_for_selector(f'tr[data-drone="{n}"][data-stale=false]', timeout=10_000)
        # the next pictures: constructor's owner changes, nothing doubles, nothing breaks
        follower.drones = [row(n, owner="B" if n == "constructor" else "A") for n in NAMES]
        follower.version += 1
        page.wait_for_selector('tr[data-drone="constructor"][data-owner="B"]', timeout=10_000)
        rows = _rows(page)
        assert sorted(r[0] for r in rows) == sorted(NAMES)
        assert {r[0]: r[1] for r in rows}["__proto__"] == "A" and all(r[2] == "false" for r in rows)
        assert page.locator("#drones circle.drone").count() == len(NAMES)
        assert page.locator("#conn").get_attribute("data-state") == "live"
    assert errors == []


def test_an_error_in_the_page_shows_it_not_live(page_errors):
    page, errors = page_errors
    follower = FakeFollower([row("d1"), row("d2")])
    with serving(follower) as port:
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_selector("tr[data-drone=d2][data-stale=false]", timeout=10_000)
        follower.drones = [row("d1"), row("d2", links=None)]  # a picture the page cannot show
        follower.version += 1
        page.wait_for_selector("#conn[data-state=error]", timeout=10_000)
        assert [r[2] for r in _rows(page)] == ["true", "true"]  # every row stale, d1's too
        assert "nothing shown is live" in page.locator("#conn").inner_text()
    with serving(FakeFollower([row("d1"), row("d2")])) as port:  # an error anywhere else in the page: the same
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_selector("tr[data-drone=d2][data-stale=false]", timeout=10_000)
        page.evaluate("setTimeout(() => { throw new Error('boom'); }, 0)")
        page.wait_for_selector("#conn[data-state=error]", timeout=10_000)
        assert [r[2] for r in _rows(page)] == ["true", "true"]
        assert "boom" in page.locator("#conn").inner_text()
    assert any("boom" in e for e in errors)
