"""The Evaluation page in headless Chromium against the real app (uvicorn, SQLite, the engine).

Start an evaluation from the page, watch it fill in from the event stream, see it complete with
the accuracy curves and their interval bands, the per-object bars, each policy's reliability
diagram and calibration measures and the confusion matrix drawn from the API's summary, then
open a finished trial in the Trials view. An evaluation whose world refuses some touches shows
how many trials were refused, and why; a refused trial opens in the Trials view with the touches
made before the refusal, the refused touch and no answer.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import httpx
import pytest
import uvicorn

from app.cli.serve import GracefulServer, listening_url
from app.config import Settings
from app.main import API_PREFIX, create_app
from tests.app.conftest import experiment1_document
from tests.app.served import start_in_thread
from tests.app.waits import finished, wait_until
from tests.e2e.conftest import PageErrors, save_screenshot

pytestmark = pytest.mark.browser


def expect(target: Any) -> Any:
    from playwright.sync_api import expect as playwright_expect

    return playwright_expect(target)


@dataclass
class Served:
    """The app served on a free loopback port, with an imported Experiment 1 model."""

    base_url: str
    client: httpx.Client
    model_id: int


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    database = tmp_path_factory.mktemp("evaluation-page") / "app.db"
    settings = Settings(
        _env_file=None,  # type: ignore[call-arg]
        database_url=f"sqlite:///{database}",
        hardware="mock",
        port=0,
    )
    config = uvicorn.Config(create_app(settings), host="127.0.0.1", port=0, log_level="warning")
    server = GracefulServer(config)
    thread = start_in_thread(server)
    base_url = listening_url(server, "127.0.0.1")
    client = httpx.Client(base_url=base_url + API_PREFIX, timeout=30)
    try:
        imported = client.post("/models/import", json=experiment1_document())
        assert imported.status_code == 201, imported.text
        yield Served(base_url=base_url, client=client, model_id=imported.json()["id"])
    finally:
        client.close()
        server.should_exit = True
        thread.join(timeout=15)


def chart_datasets(page: Any, canvas_id: str) -> list[dict[str, Any]]:
    """Label and data of every dataset of the Chart.js chart drawn on ``canvas_id``."""
    result: list[dict[str, Any]] = page.evaluate(
        """(id) => {
          const chart = window.Chart.getChart(document.getElementById(id));
          if (!chart) return [];
          return chart.data.datasets.map((d) => ({
            label: d.label,
            data: d.data.map((p) => (p !== null && typeof p === "object" ? p.y : p)),
            fill: d.fill ?? null,
          }));
        }""",
        canvas_id,
    )
    return result


def test_start_an_evaluation_watch_it_and_open_a_trial(
    page: Any, served: Served, page_errors: PageErrors
) -> None:
    page.goto(f"{served.base_url}/?viz=off#evaluation")
    expect(page.get_by_test_id("chip-events")).to_have_text("live")
    expect(page.get_by_test_id("page-evaluation")).to_be_visible()
    expect(page.get_by_test_id("eval-model")).to_have_value(str(served.model_id))
    expect(page.get_by_test_id("eval-world")).to_have_value("exp1")  # chosen for the model
    page.get_by_test_id("eval-trials").fill("12")
    page.get_by_test_id("eval-steps").fill("6")
    page.get_by_test_id("eval-seed").fill("5")
    # Record every progress text the page shows, to see it fill in while the job runs.
    page.evaluate(
        """() => {
          window.__progress = [];
          new MutationObserver(() => {
            window.__progress.push(document.getElementById("eval-progress").textContent);
          }).observe(document.getElementById("eval-progress"), {
            childList: true, subtree: true, characterData: true,
          });
        }"""
    )
    page.get_by_test_id("eval-start").click()
    expect(page.get_by_test_id("eval-status")).to_have_text("completed", timeout=120_000)

    evaluations = served.client.get("/evaluations").json()["data"]
    assert len(evaluations) == 1
    evaluation = served.client.get(f"/evaluations/{evaluations[0]['id']}").json()
    total = 2 * 4 * 12
    assert evaluation["status"] == "completed"
    assert evaluation["done"] == evaluation["total"] == total
    assert evaluation["spec"]["steps"] == 6
    expect(page.get_by_test_id("eval-progress")).to_contain_text(f"{total} of {total} trials")
    shown: list[str] = page.evaluate("window.__progress")
    counts = {int(text.split(" of ")[0]) for text in shown if " of " in text}
    assert any(0 < c < total for c in counts), f"no progress seen before the end: {shown}"

    # The curves: per policy a lower bound, an upper bound filled down to it, and the accuracy.
    summary = evaluation["summary"]["policies"]
    datasets = {d["label"]: d for d in chart_datasets(page, "chart-eval-accuracy")}
    for policy, values in summary.items():
        curve = datasets[f"{policy} (n = {values['trials']})"]
        assert curve["data"] == pytest.approx(values["accuracy_by_touch"])
        low = datasets[f"{policy} 95 % interval (low)"]["data"]
        high = datasets[f"{policy} 95 % interval"]
        assert low == pytest.approx([lo for lo, _ in values["accuracy_interval"]])
        assert high["data"] == pytest.approx([hi for _, hi in values["accuracy_interval"]])
        assert high["fill"] == "-1"
    bars = {d["label"]: d["data"] for d in chart_datasets(page, "chart-eval-objects")}
    for policy, values in summary.items():
        objects = list(values["per_object"])
        assert bars[policy] == pytest.approx([values["per_object"][o]["accuracy"] for o in objects])
    # The confusion matrix of the first policy: counts as in the summary.
    table = page.get_by_test_id("eval-confusion-table")
    expect(table).to_be_visible()
    confusion = summary["active"]["confusion"]
    rows = table.locator("tbody tr")
    expect(rows).to_have_count(len(confusion))
    first_object = next(iter(confusion))
    cells = rows.first.locator("td")
    assert [int(c) for c in cells.all_inner_texts()] == list(confusion[first_object].values())
    _expect_calibration(page, summary)
    expect(page.get_by_test_id("eval-comparison")).to_contain_text("active reaches 95")
    expect(page.get_by_test_id("eval-trial-row")).to_have_count(total)
    save_screenshot(page, "dashboard-evaluation", docs=True)

    # A finished trial opens, read-only, in the Trials view.
    row = page.get_by_test_id("eval-trial-row").first  # the newest: number == total
    number = int(row.locator("td").first.inner_text())
    row.click()
    expect(page.get_by_test_id("page-trials")).to_be_visible()
    trial = served.client.get(f"/evaluations/{evaluation['id']}/trials/{number}").json()
    expect(page.locator("#trial-title")).to_contain_text(
        f"Evaluation #{evaluation['id']}, trial {number}"
    )
    expect(page.get_by_test_id("step-row")).to_have_count(trial["touches"])
    expect(page.get_by_test_id("trial-result-object")).to_have_text(trial["answer"])
    last_row = page.get_by_test_id("step-row").last.locator("td")
    assert last_row.nth(3).inner_text() == trial["record"]["answers"][-1]
    for button in ("trial-pause", "trial-resume", "trial-stop"):
        expect(page.get_by_test_id(button)).to_be_disabled()
    save_screenshot(page, "dashboard-evaluation-trial")
    assert page_errors.exceptions == []


def _expect_calibration(page: Any, summary: dict[str, Any]) -> None:
    """The reliability diagram and the calibration table show each policy's calibration."""
    points = page.evaluate(
        """() => window.Chart.getChart(document.getElementById("chart-eval-reliability"))
          .data.datasets.map((d) => ({
            label: d.label, x: d.data.map((p) => p.x), y: d.data.map((p) => p.y),
            count: d.data.map((p) => p.count ?? null),
          }))"""
    )
    by_label = {p["label"]: p for p in points}
    diagonal = by_label["calibrated"]
    assert (diagonal["x"], diagonal["y"]) == ([0, 1], [0, 1])
    rows = page.get_by_test_id("eval-calibration-row")
    expect(rows).to_have_count(2 * len(summary))
    for policy, values in summary.items():
        scored = values["calibration"]["all_touches"]
        [drawn] = [p for label, p in by_label.items() if label.startswith(f"{policy} (ECE ")]
        used = [b for b in scored["reliability"] if b["count"]]
        assert drawn["x"] == pytest.approx([b["mean_confidence"] for b in used])
        assert drawn["y"] == pytest.approx([b["accuracy"] for b in used])
        assert drawn["count"] == [b["count"] for b in used]
        assert sum(drawn["count"]) == values["trials"] * len(values["accuracy_by_touch"])
        for scope, key in (("every touch", "all_touches"), ("at T", "final")):
            measures = values["calibration"][key]
            row = page.locator(
                f"[data-testid=eval-calibration-row][data-policy={policy}][data-scope='{scope}']"
            )
            expect(row).to_have_count(1)
            ece = row.get_by_test_id("eval-ece").inner_text()
            assert float(ece) == pytest.approx(measures["ece"], rel=5e-3, abs=1e-6)
            sure = measures["sure_and_wrong"]
            expect(row.get_by_test_id("eval-sure-wrong")).to_contain_text(
                f"{sure['wrong']} of {sure['sure']}"
            )
            cells = row.locator("td").all_inner_texts()
            assert int(cells[0]) == measures["answers"]
            assert float(cells[2]) == pytest.approx(measures["brier"], rel=5e-3, abs=1e-6)
            assert float(cells[3]) == pytest.approx(measures["log_loss"], rel=5e-3, abs=1e-6)
            null = row.get_by_test_id("eval-ece-null").inner_text().split(", ")
            expected = measures["ece_if_calibrated"]
            assert float(null[0]) == pytest.approx(expected["mean"], rel=5e-3, abs=1e-6)
            assert float(null[1]) == pytest.approx(expected["p95"], rel=5e-3, abs=1e-6)
        # After each touch: ECE and wrong/sure, as many cells as touches.
        by_touch = values["calibration"]["by_touch"]
        wrong_sure = page.locator(
            f"[data-testid=eval-sure-wrong-by-touch][data-policy={policy}] td"
        )
        assert wrong_sure.all_inner_texts() == [
            f"{t['sure_and_wrong']['wrong']}/{t['sure_and_wrong']['sure']}" for t in by_touch
        ]
        eces = page.locator(f"[data-testid=eval-ece-by-touch][data-policy={policy}] td")
        shown = [float(v) for v in eces.all_inner_texts()]
        assert shown == pytest.approx([t["ece"] for t in by_touch], rel=5e-3, abs=1e-6)
    expect(page.get_by_test_id("eval-calibration")).to_contain_text("sure (p ≥ 0.95) and wrong")
    page.get_by_test_id("eval-calibration").scroll_into_view_if_needed()
    save_screenshot(page, "dashboard-evaluation-calibration")


#: Actions beyond this refuse the touch in :class:`_CornerRefusingWorld` (the box's corner).
CORNER = 1.3


class _CornerRefusingWorld:
    """Experiment 1, except that an action beyond :data:`CORNER` is refused like an overload."""

    def __init__(self, world: Any) -> None:
        self._world = world
        self.object_names = world.object_names

    def observe(self, index: int, actions: Any, rng: Any) -> Any:
        from core.errors import TouchRefused

        if actions[0, 0] > CORNER:
            raise TouchRefused("ServoHardwareError", "servo FFJ3 (ID 1): OVERLOAD")
        return self._world.observe(index, actions, rng)


def test_refused_trials_are_counted_and_listed(
    page: Any, served: Served, page_errors: PageErrors, monkeypatch: pytest.MonkeyPatch
) -> None:
    from app.evaluation import runner
    from app.evaluation.context import TrialContext

    class CornerContext(TrialContext):
        def _world(self) -> Any:
            return _CornerRefusingWorld(super()._world())

    monkeypatch.setattr(runner, "TrialContext", CornerContext)
    body = {"model_id": served.model_id, "world": "exp1", "trials_per_target": 5, "steps": 4}
    created = served.client.post("/evaluations", json=body)
    assert created.status_code == 202, created.text
    path = f"/evaluations/{created.json()['id']}"
    evaluation = wait_until(served.client, path, finished, 120)
    assert evaluation["status"] == "completed", evaluation
    summary = evaluation["summary"]
    refused = summary["refused_trials"]
    assert 0 < refused < evaluation["total"]

    page.goto(f"{served.base_url}/?viz=off#evaluation")
    expect(page.locator("#eval-title")).to_contain_text(f"Evaluation #{evaluation['id']}")
    expect(page.get_by_test_id("eval-progress")).to_contain_text(
        f"{refused} refused by the rig (left out of the accuracy)"
    )
    labels = {d["label"] for d in chart_datasets(page, "chart-eval-accuracy")}
    for policy, values in summary["policies"].items():
        extra = f", {values['refused']} refused" if values["refused"] else ""
        assert f"{policy} (n = {values['trials']}{extra})" in labels
    refusals = page.get_by_test_id("eval-trial-refusal")
    expect(refusals).to_have_count(refused)
    expect(refusals.first).to_contain_text("ServoHardwareError: servo FFJ3 (ID 1): OVERLOAD")
    save_screenshot(page, "dashboard-evaluation-refused", full_page=True)

    # A refused trial opens in the Trials view: the touches made before the refusal, then the
    # refused touch with its action and the device's reason, and no answer.
    trials = served.client.get(f"{path}/trials?limit=1000").json()["data"]
    refused_rows = [t for t in trials if t["refused"]]
    assert len(refused_rows) == refused
    # One refused at its first touch and one after some touches (seed 0 gives both).
    chosen = {t["touches"] == 0: t for t in refused_rows}
    assert set(chosen) == {True, False}, [(t["number"], t["touches"]) for t in refused_rows]
    first = next(iter(chosen.values()))
    for t in chosen.values():
        if t is first:  # its row in the list, newest first, is clickable
            row = page.get_by_test_id("eval-trial-row").nth(evaluation["done"] - t["number"])
            expect(row.locator("td").first).to_have_text(str(t["number"]))
            row.click()
        else:
            page.goto(
                f"{served.base_url}/?viz=off#trials?evaluation={evaluation['id']}"
                f"&trial={t['number']}"
            )
        _expect_refused_trial_view(page, served, evaluation["id"], t)
    save_screenshot(page, "dashboard-evaluation-refused-trial")
    assert page_errors.exceptions == []


def _expect_refused_trial_view(page: Any, served: Served, evaluation_id: int, row: Any) -> None:
    """The Trials view shows refused trial ``row`` (a trial list row of the API)."""
    view = served.client.get(f"/evaluations/{evaluation_id}/trials/{row['number']}").json()
    refusal, record = view["refusal"], view["record"]
    expect(page.get_by_test_id("page-trials")).to_be_visible()
    expect(page.locator("#trial-title")).to_contain_text(
        f"Evaluation #{evaluation_id}, trial {row['number']} — {view['policy']}"
    )
    expect(page.get_by_test_id("trial-status")).to_have_text("refused by the rig")
    expect(page.get_by_test_id("trial-refusal")).to_have_text(
        f"{refusal['error']}: {refusal['reason']}"
    )
    expect(page.get_by_test_id("trial-result")).to_contain_text(
        f"Refused by the rig at touch {refusal['touch']}"
    )
    expect(page.get_by_test_id("trial-result")).to_contain_text("no answer")
    expect(page.get_by_test_id("trial-result-object")).to_have_count(0)
    expect(page.get_by_test_id("trial-nearest")).to_have_text("none (refused)")
    expect(page.get_by_test_id("trial-touches")).to_have_text(
        f"{view['touches']} (touch {refusal['touch']} refused)"
    )
    # The touches before the refusal, each with its answer and posterior, as for any trial.
    steps = page.get_by_test_id("step-row")
    expect(steps).to_have_count(view["touches"])
    for t in range(view["touches"]):
        cells = steps.nth(t).locator("td")
        assert cells.nth(0).inner_text() == str(t + 1)
        assert cells.nth(3).inner_text() == record["answers"][t]
        shown = cells.nth(5).inner_text()
        for name, p in zip(view["objects"], record["probabilities"][t], strict=True):
            assert f"{name} " in shown
            assert p >= 0
    # The refused touch last, marked, with its action and the device's reason.
    refused_row = page.get_by_test_id("step-refused")
    expect(refused_row).to_have_count(1)
    expect(refused_row).to_have_class("refused")
    cells = refused_row.locator("td")
    assert cells.nth(0).inner_text() == str(refusal["touch"])
    assert cells.nth(3).inner_text() == "refused"
    assert cells.nth(5).inner_text() == f"{refusal['error']}: {refusal['reason']}"
    action = [float(v) for v in cells.nth(1).inner_text().strip("[]").split(",")]
    assert action == pytest.approx(refusal["action"], rel=1e-2, abs=1e-3)
    assert refusal["action"][0] > CORNER  # the corner world refused it for that
    mi = chart_datasets(page, "chart-mi")
    assert mi[0]["data"] == pytest.approx(record["mutual_information"])
    posterior = chart_datasets(page, "chart-posterior")[0]["data"]
    last = record["probabilities"][-1] if view["touches"] else [0.0] * len(view["objects"])
    assert posterior == pytest.approx(last)


def test_the_trials_page_says_a_trial_stopped_by_the_confidence_rule(
    page: Any, served: Served, page_errors: PageErrors
) -> None:
    body = {
        "model_id": served.model_id,
        "mode": "simulated",
        "target": "O2",
        "seed": 4,
        "max_steps": 20,
        "tolerance": 0.0,
        "confidence_threshold": 0.9,
    }
    created = served.client.post("/trials", json=body)
    assert created.status_code == 201, created.text
    path = f"/trials/{created.json()['id']}"
    trial = wait_until(served.client, path, finished, 60)
    assert trial["status"] == "completed", trial
    assert trial["reason"] == "confident"
    page.goto(f"{served.base_url}/?viz=off#trials?trial={trial['id']}")
    expect(page.get_by_test_id("trial-stopped-by")).to_contain_text(
        f"after {trial['n_steps']} touches · completed — stopped by the confidence rule "
        "(an object reached p ≥ 0.9)"
    )
    assert page_errors.exceptions == []
