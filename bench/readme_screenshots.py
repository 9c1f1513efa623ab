"""Refresh the README's screenshots from the running demo (``docs/screenshots/*.png``).

Starts ``activetouch demo`` on free loopback ports with a fresh database in the background,
waits until it is ready, drives headless Chromium (``/usr/bin/chromium``, through Playwright) to
the Trials page (a finished trial of the default policy), the Evaluation page (a finished
evaluation on the simulated rig) and the Models page, saves the screenshots and stops the demo.
It prints what the trial shows — the mutual information of each touch and how many distinct
actions it chose — so a degenerate model (MI ≈ 0, one action repeated) is seen at once.

Run: ``python -m bench.readme_screenshots [--out docs/screenshots] [--table NAME] [--seed 7]``
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = os.environ.get("ACTIVETOUCH_CHROMIUM", "/usr/bin/chromium")
VIEWPORT: Any = {"width": 1440, "height": 1000}


def free_port() -> int:
    """A free loopback TCP port."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_ready(process: subprocess.Popen[str], timeout_s: float) -> None:
    """Read the demo's stderr until it says Ready (or fail)."""
    assert process.stderr is not None
    deadline = time.monotonic() + timeout_s
    for line in process.stderr:
        sys.stderr.write(line)
        if "Ready" in line:
            return
        if time.monotonic() > deadline:
            break
    raise SystemExit("the demo did not become ready")


def main(argv: list[str] | None = None) -> int:
    """Start the demo, take the screenshots, stop it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "screenshots")
    parser.add_argument("--table", default=None)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument(
        "--eval-trials", type=int, default=10, help="Evaluation trials per object and policy."
    )
    args = parser.parse_args(argv)
    port, viz_port = free_port(), free_port()
    database = Path(tempfile.mkdtemp(prefix="activetouch-shots-")) / "demo.db"
    command = [
        str(Path(sys.executable).parent / "activetouch"),
        "demo",
        "--port",
        str(port),
        "--viz-port",
        str(viz_port),
        "--database-url",
        f"sqlite:///{database}",
        "--no-browser",
    ]
    if args.table:
        command += ["--table", args.table]
    env = {**os.environ, "COLUMNS": "200"}
    process = subprocess.Popen(command, cwd=ROOT, stderr=subprocess.PIPE, text=True, env=env)
    try:
        wait_ready(process, 900)
        base = f"http://127.0.0.1:{port}"
        shoot(base, args)
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            process.kill()
    return 0


def shoot(base: str, args: argparse.Namespace) -> None:
    """The three pages."""
    from playwright.sync_api import expect, sync_playwright

    api = httpx.Client(base_url=f"{base}/api/v1", timeout=30)
    model = max(api.get("/models").json()["data"], key=lambda m: m["id"])
    names = [o["name"] for o in model["objects"]]
    args.out.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=CHROMIUM, args=["--headless", "--no-sandbox", "--disable-gpu"]
        )
        page = browser.new_page(viewport=VIEWPORT)
        page.set_default_timeout(30_000)
        page.goto(f"{base}/?viz=off#trials")
        page.get_by_test_id("trial-model").select_option(str(model["id"]))
        page.get_by_test_id("trial-target").select_option(names[min(1, len(names) - 1)])
        # The page's default policy (discriminative).
        page.get_by_test_id("trial-steps").fill(str(args.steps))
        page.locator("#trial-seed").fill(str(args.seed))
        page.get_by_test_id("start-trial").click()
        expect(page.get_by_test_id("trial-result")).to_be_visible(timeout=180_000)
        page.wait_for_timeout(1500)
        trials = api.get(f"/trials?model_id={model['id']}&limit=100").json()["data"]
        trial: dict[str, Any] = api.get(f"/trials/{max(t['id'] for t in trials)}").json()
        mi = [s["mutual_information"] for s in trial["steps"]]
        distinct = {tuple(round(a, 6) for a in s["action"]) for s in trial["steps"]}
        print(
            f"trial #{trial['id']}: {trial['policy']}, target {trial['target']}, answer "
            f"{trial['result']['object']}, {len(trial['steps'])} touches, "
            f"{len(distinct)} distinct actions, MI (nats) {[f'{v:.3g}' for v in mi]}"
        )
        page.screenshot(path=str(args.out / "dashboard-trial.png"), full_page=True)

        page.goto(f"{base}/?viz=off#evaluation")
        expect(page.get_by_test_id("eval-model")).to_have_value(str(model["id"]))
        page.get_by_test_id("eval-world").select_option("rig")
        page.get_by_test_id("eval-policy-discriminative").check()
        page.get_by_test_id("eval-trials").fill(str(args.eval_trials))
        page.get_by_test_id("eval-steps").fill("6")
        page.get_by_test_id("eval-start").click()
        expect(page.get_by_test_id("eval-status")).to_have_text("completed", timeout=900_000)
        page.wait_for_timeout(1500)
        page.screenshot(path=str(args.out / "dashboard-evaluation.png"), full_page=True)

        page.goto(f"{base}/?viz=off#models")
        page.wait_for_timeout(2500)
        page.screenshot(path=str(args.out / "dashboard-models.png"), full_page=True)
        browser.close()
    for name in ("dashboard-trial", "dashboard-evaluation", "dashboard-models"):
        path = args.out / f"{name}.png"
        print(f"wrote {path} ({path.stat().st_size} bytes)")


if __name__ == "__main__":
    raise SystemExit(main())
