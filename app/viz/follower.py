"""Following the web app: keeps a :class:`~app.viz.ManifoldView` in step with its trials.

:class:`TrialFollower` listens to the app's event stream (parsed by :func:`sse_events`) and draws
each trial it hears of, fetched through the REST API alone, so the view works beside any server,
in-process or not. :func:`wait_for_clients` and :func:`wait_for_belief_mean` wait until a view has
browsers connected or shows a given belief.
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from app.viz.geometry import FloatArray
from app.viz.view import ManifoldView
from core.types import GaussianBelief


def _belief_from(mean: Any, cov: Any) -> GaussianBelief:
    mu = np.asarray(mean, dtype=np.float64)
    return GaussianBelief(mean=mu, cov=np.asarray(cov, dtype=np.float64).reshape(mu.size, mu.size))


def sse_events(lines: Iterator[str]) -> Iterator[tuple[str, str, str]]:
    """Parse a server-sent event stream into (id, event type, data) triples.

    Args:
        lines: The stream's lines, without line endings.
    """
    event_id, event_type = "", "message"
    data: list[str] = []
    for line in lines:
        if line == "":
            if data:
                yield event_id, event_type, "\n".join(data)
            event_type, data = "message", []
            continue
        if line.startswith(":"):
            continue
        field, _, value = line.partition(":")
        value = value.removeprefix(" ")
        if field == "id":
            event_id = value
        elif field == "event":
            event_type = value
        elif field == "data":
            data.append(value)


class TrialFollower:
    """Keeps a :class:`ManifoldView` in step with the web app's trials (REST + events only).

    Listens to ``GET /api/v1/events``; on any event that names a trial it fetches
    ``GET /api/v1/trials/{id}`` and draws its belief, mean path and nearest object (loading the
    trial's model through ``GET /api/v1/models/{id}/export`` when it changes), and the planned
    trajectory of the step when the step carries one. Runs in a daemon thread; reconnects with
    ``Last-Event-ID`` when the stream drops.

    Args:
        view: The view to update.
        base_url: The web app, e.g. ``http://127.0.0.1:8000``.
        token: API token, if the server wants one.
        on_error: Called with each exception the loop survives (default: ignore).
    """

    def __init__(
        self,
        view: ManifoldView,
        base_url: str,
        token: str | None = None,
        on_error: Callable[[Exception], None] | None = None,
    ) -> None:
        import httpx

        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._client = httpx.Client(base_url=base_url.rstrip("/"), headers=headers, timeout=10.0)
        self._view = view
        self._on_error = on_error
        self._stop = threading.Event()
        self._model_id: Any = None
        self._trial_id: Any = None
        self._last_event_id = ""
        self._response: Any = None
        self._thread = threading.Thread(target=self._run, name="viz-follower", daemon=True)

    def start(self) -> TrialFollower:
        """Start following; returns self."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop following: close the event stream (so the server sees the client go), join."""
        self._stop.set()
        response = self._response
        if response is not None:
            with contextlib.suppress(Exception):
                response.close()
        self._client.close()
        self._thread.join(timeout=1.0)

    def show_model(self, model_id: Any) -> None:
        """Load model ``model_id`` from the app and show it."""
        from app.documents.model import model_from_document

        response = self._client.get(f"/api/v1/models/{model_id}/export")
        response.raise_for_status()
        self._view.show_model(model_from_document(response.json()))
        self._model_id = model_id

    def show_trial(self, trial_id: Any) -> None:
        """Fetch trial ``trial_id`` and draw its current state."""
        response = self._client.get(f"/api/v1/trials/{trial_id}")
        response.raise_for_status()
        trial = response.json()
        if trial.get("model_id") != self._model_id:
            self.show_model(trial["model_id"])
        if trial_id != self._trial_id:
            self._view.clear_trial()
            self._trial_id = trial_id
        steps = trial.get("steps") or []
        prior_mean = trial.get("prior_mean")
        means = ([prior_mean] if prior_mean is not None else []) + [
            _step_belief(step)["mean"] for step in steps
        ]
        if steps:
            last = _step_belief(steps[-1])
            self._view.show_belief(
                _belief_from(last["mean"], last["cov"]),
                path=np.asarray(means) if len(means) >= 2 else None,
                nearest_object=steps[-1].get("nearest_object"),
            )
            plan = _step_trajectory(steps[-1])
            if plan is not None:
                angles, timestep, names = plan
                self._view.show_plan(angles, timestep, joint_names=names)
        elif prior_mean is not None and trial.get("prior_cov") is not None:
            self._view.show_belief(_belief_from(prior_mean, trial["prior_cov"]))

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                headers = {"Last-Event-ID": self._last_event_id} if self._last_event_id else {}
                with self._client.stream(
                    "GET", "/api/v1/events", headers=headers, timeout=None
                ) as response:
                    self._response = response
                    response.raise_for_status()
                    for event_id, event_type, data in sse_events(response.iter_lines()):
                        if self._stop.is_set():
                            return
                        if event_id:
                            self._last_event_id = event_id
                        self._handle(event_type, data)
            except Exception as exc:  # the follower must outlive a dropped stream
                if self._stop.is_set():
                    return
                if self._on_error is not None:
                    self._on_error(exc)
                self._stop.wait(1.0)

    def _handle(self, event_type: str, data: str) -> None:
        try:
            payload = json.loads(data)
        except ValueError:
            return
        if not isinstance(payload, dict):
            return
        if isinstance(payload.get("type"), str) and isinstance(payload.get("data"), dict):
            event_type, payload = payload["type"], payload["data"]  # {"id","type","time","data"}
        trial_id = payload.get("trial_id")
        if trial_id is None and event_type.startswith("trial") and "id" in payload:
            trial_id = payload["id"]
        if trial_id is not None:
            self.show_trial(trial_id)
        elif event_type.startswith("model") and payload.get("status") == "ready":
            model_id = payload.get("model_id", payload.get("id"))
            if model_id is not None and self._trial_id is None:
                self.show_model(model_id)


def _step_belief(step: dict[str, Any]) -> dict[str, Any]:
    belief = step.get("belief")
    if isinstance(belief, dict):
        return belief
    return {"mean": step["belief_mean"], "cov": step["belief_cov"]}


def _step_trajectory(step: dict[str, Any]) -> tuple[FloatArray, float, tuple[str, ...]] | None:
    """(angles (T, J), timestep, joint names) of a step's trajectory, if it has one."""
    trajectory = step.get("trajectory")
    if not isinstance(trajectory, dict):
        return None
    angles = trajectory.get("commanded_deg") or trajectory.get("angles_deg")
    timestep = trajectory.get("dt_s") or trajectory.get("timestep_s")
    if angles is None or timestep is None:
        return None
    array = np.asarray(angles, dtype=np.float64)
    if array.ndim != 2 or array.shape[0] < 2:
        return None
    names = trajectory.get("joint_names") or ["FFJ3", "FFJ4"][: array.shape[1]]
    if len(names) != array.shape[1]:
        return None
    return array, float(timestep), tuple(str(n) for n in names)


def wait_for_clients(view: ManifoldView, count: int = 1, timeout_s: float = 10.0) -> bool:
    """Wait until ``count`` browsers are connected to ``view``; whether they were in time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if view.n_clients >= count:
            return True
        time.sleep(0.05)
    return view.n_clients >= count


def wait_for_belief_mean(
    view: ManifoldView, mean: FloatArray, timeout_s: float = 15.0, rtol: float = 1e-12
) -> bool:
    """Wait until ``view`` shows a belief whose mean is ``mean`` (shape (ds,), to ``rtol``), as
    after its follower has drawn a trial's last step; whether it did in time."""

    def shown() -> bool:
        belief = view.belief
        return belief is not None and bool(np.allclose(belief.mean, mean, rtol=rtol, atol=0))

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if shown():
            return True
        time.sleep(0.05)
    return shown()
