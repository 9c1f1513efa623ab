"""The Trials page runs the other policy on the same object and seed with one click.

A finished trial of the default policy (discriminative) shows "Run with passive"; clicking it
creates a new trial with the same model, target, seed and settings and the passive policy, and
the page follows that one; the finished passive trial offers "Run with discriminative" back.
A reload of the first trial that answers after the click (its late events fire such reloads)
must not bring the first trial back.
"""

from __future__ import annotations

import re
from typing import Any

import pytest

from tests.e2e.conftest import Demo, PageErrors, save_screenshot
from tests.e2e.test_dashboard_browser import expect, newest_trial, open_dashboard

pytestmark = pytest.mark.browser

SAME = ("model_id", "mode", "target", "seed", "max_steps", "tolerance", "prior_mean", "prior_cov")


def test_run_with_the_other_policy(page: Any, demo: Demo, page_errors: PageErrors) -> None:
    open_dashboard(page, demo)
    model = demo.get(f"/models/{demo.state.model_id}")
    target = model["objects"][1]["name"]
    page.get_by_test_id("trial-model").select_option(str(demo.state.model_id))
    page.get_by_test_id("trial-target").select_option(target)
    expect(page.get_by_test_id("trial-policy")).to_have_value("discriminative")  # the default
    page.get_by_test_id("trial-steps").fill("4")
    page.locator("#trial-seed").fill("")  # no seed given: the page records one anyway
    page.get_by_test_id("start-trial").click()
    result = page.get_by_test_id("trial-result")
    expect(result).to_be_visible(timeout=90_000)
    first = newest_trial(demo)
    assert first["policy"] == "discriminative"
    assert first["seed"] is not None

    other = page.get_by_test_id("trial-run-other")
    expect(other).to_have_text("Run with passive")
    # A reload of the first trial is held in flight while the button is clicked, and answers
    # only once the page shows the new trial.
    held: list[Any] = []
    first_url = re.compile(rf"/api/v1/trials/{first['id']}$")

    def hold(route: Any) -> None:
        held.append(route)

    page.route(first_url, hold)
    page.evaluate(f"location.hash = '#trials?trial={first['id']}'")
    while not held:
        page.wait_for_timeout(20)
    other.click()
    # The new trial is created and loaded while the machine may be busy with other tests: the
    # same allowance as the trial's own run above.
    expect(page.locator("#trial-title")).to_contain_text("— passive", timeout=90_000)
    held[0].continue_()
    page.unroute(first_url)
    expect(page.get_by_test_id("trial-run-other")).to_have_text(
        "Run with discriminative", timeout=90_000
    )
    second = newest_trial(demo)
    assert second["id"] != first["id"]
    assert second["policy"] == "passive"
    assert second["status"] in ("completed", "stopped")
    for key in SAME:
        assert second[key] == first[key], key
    assert second["options"].get("simulation") == first["options"].get("simulation")
    expect(page.locator("#trial-title")).to_contain_text(f"Trial #{second['id']} — passive")
    save_screenshot(page, "dashboard-trial-other-policy")
    assert not page_errors.exceptions, page_errors.exceptions
