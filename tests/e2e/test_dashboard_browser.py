"""The dashboard in headless Chromium against the real demo (web app, SQLite, viser view).

A newcomer's path: open the dashboard, start a recognition trial with one click, watch it live,
read the recognised object; the 3D view connects. Screenshots: ``artifacts/screenshots/``.
"""

from __future__ import annotations

import csv
import io
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.viz.follower import wait_for_belief_mean, wait_for_clients
from tests.app.waits import finished, poll
from tests.e2e.conftest import DOCS_FLAG, Demo, PageErrors, record_touch_counts, save_screenshot

pytestmark = pytest.mark.browser

PAGES = ("rig", "objects", "collection", "models", "trials", "history")


def expect(target: Any) -> Any:
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(target)


def open_dashboard(page: Any, demo: Demo, hash_: str = "#trials", viz: bool = False) -> None:
    """Open the dashboard; without ``viz`` the 3D view waits for a click (software WebGL in a
    headless browser is slow enough to starve the page's own scripts)."""
    query = "" if viz else "?viz=off"
    page.goto(f"{demo.server.base_url}/{query}{hash_}")
    expect(page.get_by_test_id("chip-server")).to_contain_text("server ok")
    expect(page.get_by_test_id("chip-events")).to_have_text("live")


def newest_trial(demo: Demo) -> dict[str, Any]:
    trials = demo.get(f"/trials?model_id={demo.state.model_id}&limit=1000")["data"]
    summary = max(trials, key=lambda t: t["id"])
    detail: dict[str, Any] = demo.get(f"/trials/{summary['id']}")
    return detail


def test_every_page_renders_with_the_estop(page: Any, demo: Demo) -> None:
    open_dashboard(page, demo)
    for name in PAGES:
        page.get_by_test_id(f"nav-{name}").click()
        expect(page.get_by_test_id(f"page-{name}")).to_be_visible()
        estop = page.get_by_test_id("estop")
        expect(estop).to_be_visible()
        expect(estop).to_be_enabled()
        assert estop.get_attribute("aria-label", timeout=1000).startswith("Emergency stop")
        for other in PAGES:
            if other != name:
                expect(page.get_by_test_id(f"page-{other}")).to_be_hidden()
    # Models: the fitted model is listed, its manifold and hyperparameters are shown.
    page.get_by_test_id("nav-models").click()
    expect(page.get_by_test_id("model-row")).to_have_count(1)
    expect(page.get_by_test_id("model-detail")).to_be_visible()
    model = demo.get(f"/models/{demo.state.model_id}")
    expect(page.get_by_test_id("hyper-table").locator("tbody tr")).to_have_count(
        len(model["hyperparameters"])
    )
    # The demo's collection touched every placement twice (the default): the fit measured the
    # placement effect and holds it in its own likelihood, and the page says so.
    effect = model["placement_effect"]
    assert effect is not None
    assert effect["in_training_covariance"] is True
    expect(page.get_by_test_id("model-detail")).to_contain_text(
        "in the fit's likelihood and in scoring trials"
    )
    expect(page.get_by_test_id("model-detail")).to_contain_text("one per feature")
    # Every choice of the fit form shows its whole label (padding and the arrow beside it).
    clipped = page.evaluate(
        """() => {
          const ctx = document.createElement("canvas").getContext("2d");
          return [...document.querySelectorAll("#fit-form select")].filter((select) => {
            const style = getComputedStyle(select);
            ctx.font = style.font;
            const text = select.options[select.selectedIndex]?.text ?? "";
            const room = select.clientWidth - parseFloat(style.paddingLeft)
              - parseFloat(style.paddingRight) - 16;
            return ctx.measureText(text).width > room;
          }).map((select) => select.id);
        }"""
    )
    assert clipped == [], f"fit form choices cut short: {clipped}"
    expect(page.get_by_test_id("model-export")).to_have_attribute(
        "href", f"api/v1/models/{demo.state.model_id}/export"
    )
    save_screenshot(page, "dashboard-models", docs=True)
    # Collection: the demo's training set is listed with its size.
    page.get_by_test_id("nav-collection").click()
    dataset = demo.get(f"/datasets/{demo.state.dataset_id}")
    row = page.get_by_test_id("dataset-row").first
    expect(row).to_contain_text(str(dataset["n_samples"]))


def test_demo_trial_through_the_ui(page: Any, demo: Demo) -> None:
    """One click starts a trial; the page follows it live and shows the recognised object."""
    open_dashboard(page, demo)
    model = demo.get(f"/models/{demo.state.model_id}")
    names = [o["name"] for o in model["objects"]]
    target = names[2]
    page.get_by_test_id("trial-model").select_option(str(demo.state.model_id))
    expect(page.get_by_test_id("trial-target").locator("option")).to_have_count(len(names) + 1)
    page.get_by_test_id("trial-target").select_option(target)
    page.get_by_test_id("trial-policy").select_option("active")
    page.get_by_test_id("trial-steps").fill("10")
    page.locator("#trial-seed").fill("7")
    expect(page.get_by_test_id("trial-mode")).to_have_value(demo.state.mode)

    started = time.perf_counter()
    record_touch_counts(page)
    page.get_by_test_id("start-trial").click()
    expect(page.get_by_test_id("step-row").first).to_be_visible(timeout=30_000)
    save_screenshot(page, "dashboard-trial-live")
    result = page.get_by_test_id("trial-result")
    expect(result).to_be_visible(timeout=60_000)
    elapsed_s = time.perf_counter() - started
    print(f"start trial → result shown: {elapsed_s:.1f} s")

    trial = newest_trial(demo)
    assert trial["status"] == "completed"
    assert trial["target"] == target
    shown = page.get_by_test_id("trial-result-object").inner_text()
    assert shown == trial["result"]["object"]
    assert shown in names
    # The active policy names the target within 10 touches on the simulated rig (seed fixed).
    assert trial["result"]["correct"] is True
    expect(result).to_contain_text("✓ correct")
    expect(page.get_by_test_id("step-row")).to_have_count(len(trial["steps"]))
    expect(page.get_by_test_id("trial-touches")).to_have_text(
        f"{len(trial['steps'])} / {trial['max_steps']}"
    )
    expect(page.get_by_test_id("trial-nearest")).to_have_text(trial["steps"][-1]["nearest_object"])
    seen = set(page.evaluate("() => window.__touchCounts"))
    assert len(seen) >= 2, f"the touch count was shown only as {seen}: no live update"
    for action in ("pause", "resume", "stop"):
        expect(page.get_by_test_id(f"trial-{action}")).to_be_disabled()
    page.get_by_test_id("trial-live").scroll_into_view_if_needed()
    save_screenshot(page, "dashboard-trial", docs=True, full_page=True)


def test_viser_view_connects_and_follows_the_trial(
    page: Any, browser: Any, demo: Demo, page_errors: PageErrors
) -> None:
    assert demo.server.live is not None
    view = demo.server.live.view
    assert view is not None
    open_dashboard(page, demo, viz=True)
    frame = page.get_by_test_id("viser-frame")
    expect(frame).to_be_visible()
    assert f":{view.port}/" in (frame.get_attribute("src") or "")
    assert wait_for_clients(view, 1, timeout_s=90), "the embedded viser client did not connect"
    # The follower shows the model, and follows a trial started through the API to its end.
    assert view.model is not None
    names = [o["name"] for o in demo.get(f"/models/{demo.state.model_id}")["objects"]]
    assert list(view.model.object_names) == names
    body: dict[str, Any] = {
        "model_id": demo.state.model_id,
        "mode": demo.state.mode,
        "policy": "active",
        "max_steps": 5,
        "target": names[0],
        "seed": 3,
    }
    if demo.state.mode == "simulated":
        body["simulation"] = {"world": demo.state.world, "step_interval_s": 0.0}
    created = demo.server.client.post("/trials", json=body)
    assert created.status_code == 201, created.text
    path = f"/trials/{created.json()['id']}"
    trial = poll(lambda: demo.get(path), finished, 60, path)
    final_mean = np.asarray(trial["steps"][-1]["belief"]["mean"])
    wait_for_belief_mean(view, final_mean)
    assert view.belief is not None
    np.testing.assert_allclose(view.belief.mean, final_mean, rtol=1e-12)
    # The view on its own page, for the screenshot.
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    try:
        alone = context.new_page()
        alone.on("pageerror", lambda error: page_errors.exceptions.append(str(error)))
        alone.goto(view.url)
        assert wait_for_clients(view, 2, timeout_s=90), "the viser page alone did not connect"
        # The client eases the camera in and fades the scene in; with software WebGL at a few
        # frames a second that takes long: wait more when refreshing the README's copy.
        alone.wait_for_timeout(25_000 if os.environ.get(DOCS_FLAG) == "1" else 6_000)
        # Taking it waits for a frame from software WebGL, which can take long on a busy machine.
        save_screenshot(alone, "viser-view", docs=True, timeout=120_000)
    finally:
        context.close()


def test_history_compares_policies_and_exports(page: Any, demo: Demo, tmp_path: Path) -> None:
    open_dashboard(page, demo, "#history")
    page.locator("#hist-model").select_option(str(demo.state.model_id))
    page.locator("#batch-n").fill("2")
    page.get_by_test_id("batch-start").click()
    expect(page.get_by_test_id("batch-status")).to_contain_text("Batch done", timeout=90_000)
    trials = demo.get(f"/trials?model_id={demo.state.model_id}&limit=1000")["data"]
    expect(page.get_by_test_id("history-row")).to_have_count(len(trials))
    assert {t["policy"] for t in trials} >= {"active", "passive"}
    expect(page.locator("#accuracy-note")).to_contain_text("Fraction of finished trials")
    with page.expect_download() as download_info:
        page.get_by_test_id("export-csv").click()
    path = tmp_path / "trials.csv"
    download_info.value.save_as(path)
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    assert len(rows) == len(trials)
    assert {int(r["id"]) for r in rows} == {t["id"] for t in trials}
    by_id = {t["id"]: t for t in trials}
    for row in rows:
        result = by_id[int(row["id"])]["result"]
        assert row["result"] == (result["object"] if result else "")
    save_screenshot(page, "dashboard-history", docs=True)


def test_collection_through_the_ui(page: Any, demo: Demo) -> None:
    """Collect a small dataset on the simulated rig from the Collection page, with the shared
    design (every object is touched with the same actions) and a placement per touch."""
    open_dashboard(page, demo, "#collection")
    rows = page.locator("#col-objects .object-row")
    objects = demo.get("/objects")["data"]
    expect(rows).to_have_count(len([o for o in objects if o["slot"] is not None]))
    n_objects = rows.count()
    page.locator("#col-name").fill("browser test")
    page.locator("#col-samples").fill("2")
    design = page.get_by_test_id("collection-design")
    help_text = page.get_by_test_id("collection-design-help")
    # The default is the API's and collect's: adaptive (docs/usage.md).
    expect(design).to_have_value("adaptive")
    expect(help_text).to_contain_text("rounds at the actions the planners would choose")
    assert [o.get_attribute("value") for o in design.locator("option").all()] == [
        "adaptive",
        "random",
        "shared",
        "teaching",
    ]
    design.select_option("random")
    expect(help_text).to_contain_text("a fresh action")
    design.select_option("shared")
    expect(help_text).to_contain_text("applied to every object")
    # Placements: empty is the default, which the form states.
    placements = page.get_by_test_id("collection-placements")
    expect(placements).to_have_value("")
    expect(page.get_by_test_id("collection-placements-help")).to_contain_text(
        "Empty: the default, three placements for every four touches"
    )
    placements.fill("2")
    before = len(demo.get("/datasets")["data"])
    page.get_by_test_id("collection-start").click()
    # The progress identifies the new run (the demo's own collection, shown before the click,
    # is "completed" too, with another count).
    expect(page.get_by_test_id("collection-progress")).to_have_text(
        f"{2 * n_objects} / {2 * n_objects}", timeout=60_000
    )
    expect(page.get_by_test_id("collection-status")).to_have_text("completed", timeout=10_000)
    expect(page.get_by_test_id("trace-note")).to_contain_text("features y =")
    expect(page.get_by_test_id("trace-note")).not_to_contain_text("no raw trace")
    # The live trace of the last touch: every tactile channel, thinned to at most 200 frames.
    drawn = page.evaluate(
        """() => {
          const chart = window.Chart.getChart("chart-trace");
          return chart ? chart.data.datasets.map((d) => [d.label, d.data.length]) : null;
        }"""
    )
    assert drawn is not None, "the tactile trace chart was not drawn"
    assert len(drawn) == 5, drawn
    assert all(0 < n <= 200 for _, n in drawn), drawn
    datasets = demo.get("/datasets")["data"]
    assert len(datasets) == before + 1
    newest = max(datasets, key=lambda d: d["id"])
    assert newest["name"] == "browser test"
    assert newest["n_samples"] == 2 * n_objects
    runs = demo.get("/collections?limit=100")["data"]
    assert [
        (r["params"]["action_design"], r["params"]["placements"])
        for r in runs
        if r["dataset_id"] == newest["id"]
    ] == [("shared", 2)]
    # The stored dataset: the same two actions on every object (each in its own order).
    samples = demo.get(f"/datasets/{newest['id']}/export?format=json")["samples"]
    actions: dict[str, list[list[float]]] = {}
    placed: dict[str, list[int]] = {}
    for sample in samples:
        actions.setdefault(sample["object"], []).append(sample["action"])
        placed.setdefault(sample["object"], []).append(sample["placement"])
    assert all(p == [0, 1] for p in placed.values()), placed
    assert len(actions) == n_objects
    first = next(iter(actions.values()))
    assert len(first) == 2, first
    assert first[0] != first[1], first
    assert all(sorted(touches) == sorted(first) for touches in actions.values()), actions
    expect(page.get_by_test_id("dataset-row")).to_have_count(len(datasets))
    save_screenshot(page, "dashboard-collection")


def test_estop_halts_the_rig_and_connect_recovers(page: Any, demo: Demo) -> None:
    """The e-stop button works from any page; Rig → Connect brings the rig back."""
    open_dashboard(page, demo, "#models")
    page.get_by_test_id("estop").click()
    expect(page.get_by_test_id("toasts")).to_contain_text("Emergency stop sent")
    assert demo.get("/rig")["state"] == "estopped"
    expect(page.get_by_test_id("chip-rig")).to_contain_text("estopped")
    page.get_by_test_id("nav-rig").click()
    expect(page.get_by_test_id("rig-summary")).to_contain_text("estopped")
    page.get_by_test_id("rig-connect").click()
    expect(page.get_by_test_id("rig-summary")).to_contain_text("idle")
    assert demo.get("/rig")["state"] == "idle"
    save_screenshot(page, "dashboard-rig")
