"""Off loopback in headless Chromium: the dashboard asks for the token once, follows a trial live
on the session cookie (events included), embeds the 3D view through the app's proxy, lists the
changes in History, and after sign-out the API answers 401 again.

The demo runs on 127.0.0.1 with ``require_auth_for_reads`` (what a non-loopback bind turns on;
tests/app/test_security_gate.py checks that ``host=0.0.0.0`` does), so no network interface is
opened by the test.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from typing import Any

import pytest

from app.security.sessions import SESSION_COOKIE
from app.viz.follower import wait_for_clients
from tests.e2e.conftest import Demo, record_touch_counts, running_demo, save_screenshot

pytestmark = pytest.mark.browser

TOKEN = "browser-test-token-7c1f"


def expect(target: Any) -> Any:
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(target)


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Demo]:
    """The demo (Experiment 1 world: no collection) with reads locked behind the token."""
    with running_demo(
        tmp_path_factory.mktemp("signin"),
        settings_overrides={"require_auth_for_reads": True},
        world="exp1",
        latent_dim=1,
        api_token=TOKEN,
    ) as running:
        yield running


def sign_in(page: Any, token: str = TOKEN) -> None:
    expect(page.get_by_test_id("signin-dialog")).to_be_visible()
    page.get_by_test_id("signin-token").fill(token)
    page.get_by_test_id("signin-submit").click()


def test_sign_in_follow_a_trial_live_and_sign_out(page: Any, demo: Demo) -> None:
    base = demo.server.base_url
    requested: list[str] = []
    page.on("request", lambda request: requested.append(request.url))
    page.goto(f"{base}/?viz=off#trials")
    # Nothing is shown before the sign-in; the server says only that auth is required.
    expect(page.get_by_test_id("signin-dialog")).to_be_visible()
    expect(page.get_by_test_id("chip-server")).to_contain_text("sign-in needed")
    expect(page.get_by_test_id("trial-model").locator("option")).to_have_count(0)
    sign_in(page, "not-the-token")
    expect(page.get_by_test_id("signin-error")).to_contain_text("not this server's API token")
    save_screenshot(page, "dashboard-sign-in")
    page.get_by_test_id("signin-token").fill(TOKEN)
    page.get_by_test_id("signin-submit").click()
    expect(page.get_by_test_id("signin-dialog")).to_be_hidden()
    expect(page.get_by_test_id("chip-server")).to_contain_text("server ok")
    expect(page.get_by_test_id("chip-events")).to_have_text("live")
    expect(page.get_by_test_id("signout-button")).to_be_visible()

    # The cookie: a server session, HttpOnly (no script reads it), SameSite=Strict.
    cookies = {c["name"]: c for c in page.context.cookies()}
    session = cookies[SESSION_COOKIE]
    assert session["httpOnly"] is True
    assert session["sameSite"] == "Strict"
    assert TOKEN not in session["value"]
    assert SESSION_COOKIE not in page.evaluate("() => document.cookie")

    # A trial started from the page, followed live over the event stream.
    model = demo.get(f"/models/{demo.state.model_id}")
    target = model["objects"][1]["name"]
    page.get_by_test_id("trial-model").select_option(str(demo.state.model_id))
    page.get_by_test_id("trial-mode").select_option(demo.state.mode)
    page.get_by_test_id("trial-world").select_option(demo.state.world)
    page.get_by_test_id("trial-target").select_option(target)
    page.get_by_test_id("trial-steps").fill("8")
    page.locator("#trial-seed").fill("5")
    page.locator("#trial-interval").fill("0.2")
    record_touch_counts(page)
    page.get_by_test_id("start-trial").click()
    expect(page.get_by_test_id("step-row").first).to_be_visible(timeout=30_000)
    expect(page.get_by_test_id("trial-result")).to_be_visible(timeout=60_000)
    seen = set(page.evaluate("() => window.__touchCounts"))
    assert len(seen) >= 2, f"the touch count was shown only as {seen}: no live update"
    trials = demo.get(f"/trials?model_id={demo.state.model_id}&limit=100")["data"]
    trial_id = max(t["id"] for t in trials)

    # The e-stop from the page, then History lists both changes with the client and outcome.
    page.get_by_test_id("estop").click()
    expect(page.get_by_test_id("toasts")).to_contain_text("Emergency stop sent")
    page.get_by_test_id("nav-history").click()
    rows = page.get_by_test_id("audit-row")
    started = rows.filter(has_text="POST /api/v1/trials").filter(has_text="201")
    # Rows are written a moment after each answer; the page re-reads them every 3 s.
    expect(started).to_have_count(1, timeout=15_000)
    expect(started.get_by_test_id("audit-client")).to_have_text("127.0.0.1")
    expect(started.get_by_test_id("audit-auth")).to_have_text("yes (signed-in dashboard)")
    estop = rows.filter(has_text="POST /api/v1/rig/estop")
    expect(estop).to_have_count(1, timeout=15_000)
    expect(estop.get_by_test_id("audit-status")).to_have_text("200")
    save_screenshot(page, "dashboard-history-audit")
    assert demo.get(f"/trials/{trial_id}")["status"] == "completed"

    # Sign out: a fresh page asks for the token again and the API refuses the browser.
    page.get_by_test_id("signout-button").click()
    expect(page.get_by_test_id("signin-dialog")).to_be_visible()
    assert SESSION_COOKIE not in {c["name"] for c in page.context.cookies()}
    for path in ("/api/v1/trials", f"/api/v1/trials/{trial_id}", "/api/v1/events?follow=false"):
        assert page.request.get(f"{base}{path}").status == 401, path
    # The token never travelled in a URL.
    assert requested
    assert not [url for url in requested if TOKEN in url]


def test_the_3d_view_is_embedded_through_the_gate(page: Any, demo: Demo) -> None:
    assert demo.server.live is not None
    view = demo.server.live.view
    base = demo.server.base_url
    page.goto(f"{base}/#trials")
    sign_in(page)
    frame = page.get_by_test_id("viser-frame")
    expect(frame).to_be_visible()
    assert (frame.get_attribute("src") or "") == f"{base}/viser/"
    # The viser client in the frame connected through the proxied websocket (viser counts a
    # client once its camera message arrives: both directions work).
    started = time.monotonic()
    assert wait_for_clients(view, 1, timeout_s=60), "the embedded view did not connect"
    print(f"3D view connected through the proxy in {time.monotonic() - started:.1f} s")


def test_the_demo_login_link_signs_in_once_and_leaves_the_address(page: Any, demo: Demo) -> None:
    """``activetouch demo`` prints ``/#token=...`` off loopback: the fragment never reaches the
    server; the page signs in with it (POST body) and drops it from the address bar."""
    page.goto(demo.server.dashboard_url.replace("/#", "/?viz=off#"))
    expect(page.get_by_test_id("chip-events")).to_have_text("live")
    expect(page.get_by_test_id("signin-dialog")).to_be_hidden()
    assert TOKEN not in page.url
    assert page.evaluate("() => location.hash") == "#trials"
    assert SESSION_COOKIE in {c["name"] for c in page.context.cookies()}


@pytest.fixture(scope="module")
def local_demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Demo]:
    """On loopback with a token: reads open, changes need the sign-in (as before)."""
    with running_demo(
        tmp_path_factory.mktemp("local"), world="exp1", latent_dim=1, api_token=TOKEN
    ) as running:
        yield running


def test_on_loopback_reads_are_open_and_a_change_asks_to_sign_in(
    page: Any, local_demo: Demo
) -> None:
    page.goto(f"{local_demo.server.base_url}/?viz=off#models")
    expect(page.get_by_test_id("chip-events")).to_have_text("live")
    expect(page.get_by_test_id("model-row")).to_have_count(1)  # read without signing in
    expect(page.get_by_test_id("signin-dialog")).to_be_hidden()
    expect(page.get_by_test_id("signin-button")).to_be_visible()
    # A change without the session: refused, and the form comes up (not modal: the E-STOP
    # stays reachable) in view.
    page.get_by_test_id("estop").click()
    expect(page.get_by_test_id("toasts")).to_contain_text("E-STOP FAILED")
    dialog = page.get_by_test_id("signin-dialog")
    expect(dialog).to_be_visible()
    expect(dialog).to_be_in_viewport()
    modal = page.evaluate("() => document.getElementById('signin-dialog').matches(':modal')")
    assert modal is False
    save_screenshot(page, "dashboard-sign-in-for-changes")
    page.get_by_test_id("signin-token").fill(TOKEN)
    page.get_by_test_id("signin-submit").click()
    expect(dialog).to_be_hidden()
    expect(page.get_by_test_id("signout-button")).to_be_visible()
    page.get_by_test_id("estop").click()
    expect(page.get_by_test_id("toasts")).to_contain_text("Emergency stop sent")
    # Sign out: reads stay open on loopback.
    page.get_by_test_id("signout-button").click()
    expect(page.get_by_test_id("signin-button")).to_be_visible()
    expect(page.get_by_test_id("model-row")).to_have_count(1)
    assert page.request.get(f"{local_demo.server.base_url}/api/v1/trials").status == 200


@pytest.fixture(scope="module")
def strict_demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Demo]:
    """Reads locked, and only two wrong tokens per minute from one address."""
    with running_demo(
        tmp_path_factory.mktemp("strict"),
        settings_overrides={"require_auth_for_reads": True, "auth_max_failures": 2},
        world="exp1",
        latent_dim=1,
        api_token=TOKEN,
    ) as running:
        yield running


def test_too_many_wrong_tokens_the_form_says_when_to_retry(page: Any, strict_demo: Demo) -> None:
    page.goto(f"{strict_demo.server.base_url}/?viz=off")
    error = page.get_by_test_id("signin-error")
    for _ in range(2):
        sign_in(page, "not-the-token")
        expect(error).to_have_text("That is not this server's API token.")
        expect(page.get_by_test_id("signin-submit")).to_be_enabled()  # the answer is in
    # Over the limit: even the right token is refused; the form shows the server's message.
    sign_in(page, TOKEN)
    expect(error).to_have_text(re.compile(r"^Too many wrong API tokens .* Try again in \d+ s"))
    expect(page.get_by_test_id("signin-dialog")).to_be_visible()
