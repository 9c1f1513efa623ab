"""Every request body the API cannot use is answered 4xx with a JSON ``detail``, never a 500.

The routes come from the app's own OpenAPI schema, so a new route is swept without editing this
file. Each route that takes a body receives whole bodies that are not what it wants (empty, not
JSON, truncated, the non-standard constants ``NaN``/``Infinity`` Python's ``json`` accepts,
numbers beyond float or int range, nesting deeper than the parser's recursion, invalid UTF-8,
wrong content types, a body over the upload limit) and, for its JSON example body, every field
replaced in turn by such a value. Routes without a body get the junk bodies too: they must
ignore them. The app runs on a database that holds a dataset, a ready model and a scripted trial
with a step, so the ids in paths exist and a body is the only thing wrong.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any, get_args

import pytest

from app.main import create_app
from app.schemas import EvaluationCreate, ModelCreate, TrialCreate
from app.states import Action
from tests.app.conftest import (
    TestClient,
    experiment1_csv,
    experiment1_document,
    import_model,
    make_settings,
)

API = "/api/v1"
UPLOAD_LIMIT_BYTES = 2 * 1024 * 1024
ONE_MIB = 1024 * 1024

#: Replaced by a raw JSON token after ``json.dumps`` (``1e400`` cannot be written from Python).
_SLOT = "\u0000slot\u0000"

#: Raw JSON values no field accepts: not finite, beyond int/float range, nested too deep, huge.
BAD_VALUES: dict[str, bytes] = {
    "NaN": b"NaN",
    "Infinity": b"Infinity",
    "-Infinity": b"-Infinity",
    "1e400": b"1e400",
    "-1e400": b"-1e400",
    "5000-digit integer": b"9" * 5000,
    "array nested 100000 deep": b"[" * 100_000 + b"]" * 100_000,
    "array nested 500 deep": b"[" * 500 + b"]" * 500,
    "1 MiB string": json.dumps("n" * ONE_MIB).encode(),
    "lone surrogate": b'"\\ud800"',
    "list of 5000 numbers": b"[" + b",".join([b"0.5"] * 5000) + b"]",
}

#: Bad values that are still plain JSON a free-form record (a touch's ``trajectory``) may hold.
WELL_FORMED_IN_A_RECORD = {"list of 5000 numbers"}

#: Bodies sent as ``application/json`` that are not the JSON object any route wants.
BAD_JSON: dict[str, bytes] = {
    "empty": b"",
    "not JSON": b"this is not JSON",
    "truncated JSON": b'{"name": [1, 2',
    "JSON array": b"[1, 2, 3]",
    "JSON string": b'"text"',
    "JSON null": b"null",
    "JSON number": b"42",
    "bare NaN": b"NaN",
    "object of non-finite numbers": b'{"a": NaN, "b": Infinity, "c": -Infinity, "d": 1e400}',
    "5000-digit integer": b'{"a": ' + b"9" * 5000 + b"}",
    "array nested 100000 deep": b"[" * 100_000 + b"]" * 100_000,
    "object nested 100000 deep": b'{"a": ' * 100_000 + b"1" + b"}" * 100_000,
    "invalid UTF-8": b'{"name": "\xff\xfe\xc3("}',
    "UTF-16": '{"name": "x"}'.encode("utf-16"),
    "lone surrogate escape": b'{"name": "\\ud800"}',
    "over the upload limit": b'{"name": "' + b"n" * UPLOAD_LIMIT_BYTES + b'"}',
}

#: Whole bodies that are not the JSON object any route wants: (content type, bytes).
BAD_BODIES: dict[str, tuple[str | None, bytes]] = {
    **{case: ("application/json", body) for case, body in BAD_JSON.items()},
    "no content type": (None, b"\xff\x00 not JSON"),
    "text/plain": ("text/plain", b"\xff\xfe not UTF-8"),
    "XML": ("application/xml", b"<name>x</name>"),
    "form": ("application/x-www-form-urlencoded", b"name=x&name=%FF"),
    "multipart without parts": ("multipart/form-data; boundary=xyz", b"--xyz\r\nnonsense"),
    "multipart without boundary": ("multipart/form-data", b"--xyz\r\n\r\n--xyz--"),
}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    """An app (serial hardware without ports, so the rig answers 503 without moving) holding a
    dataset, a ready model and a scripted trial with one step."""
    settings = make_settings(
        tmp_path_factory.mktemp("malformed"),
        hardware="serial",
        max_upload_bytes=UPLOAD_LIMIT_BYTES,
        max_training_touches=200,
    )
    with TestClient(create_app(settings), raise_server_exceptions=False) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def ids(client: TestClient) -> dict[str, int]:
    """The ids of the rows the examples refer to (and of path parameters).

    ``trial_id`` is a scripted trial with a step that takes up to 1000 observations;
    ``spare_trial_id`` is the one the routes without a body (pause, stop, abort) act on, so
    the first stays open to tell a refused observation from a finished trial.
    """
    dataset = client.post(
        f"{API}/datasets", content=experiment1_csv(), headers={"content-type": "text/csv"}
    )
    assert dataset.status_code == 201, dataset.text
    model_id = import_model(client)
    trial_ids = []
    for _ in range(2):
        trial = client.post(
            f"{API}/trials",
            json={
                "model_id": model_id,
                "mode": "scripted",
                "target": "O1",
                "seed": 1,
                "max_steps": 1000,
            },
        )
        assert trial.status_code == 201, trial.text
        trial_ids.append(trial.json()["id"])
    action = client.get(f"{API}/trials/{trial_ids[0]}/next-action").json()["action"]
    step = client.post(
        f"{API}/trials/{trial_ids[0]}/observations",
        json={"action": action, "observation": [0.1, 0.2, 0.3]},
    )
    assert step.status_code == 200, step.text
    return {
        "dataset_id": dataset.json()["id"],
        "model_id": model_id,
        "trial_id": trial_ids[0],
        "spare_trial_id": trial_ids[1],
        "collection_id": 1,
        "evaluation_id": 1,
    }


def example_bodies(ids: dict[str, int]) -> dict[str, dict[str, Any]]:
    """A JSON body each route accepts (path template → body), every field filled in."""
    return {
        "/datasets": {
            "name": "touches",
            "samples": [
                {"object": name, "action": [0.1 * i], "observation": [0.2, 0.3]}
                for name in ("A", "B")
                for i in range(2)
            ],
        },
        "/models": {
            "dataset_id": ids["dataset_id"],
            "latent_dim": 2,
            "noise_model": "independent",
            "optimizer": "lbfgs",
            "restarts": 0,
            "seed": 1,
            "max_iterations": 5,
        },
        "/models/import": {
            **experiment1_document(touches_per_object=3),
            "name": "imported",
            "diagnostics": {
                "starts_log_likelihood": [-10.0],
                "best_start": 0,
                "iterations": 3,
                "converged": True,
                "message": "converged",
                "jitter_used": 0.0,
                "hyperparameters_at_bounds": ["noise_variance[0]"],
            },
            "latent_selection": {
                "chosen": 1,
                "best": 1,
                "n_folds": 2,
                "candidates": [
                    {
                        "latent_dim": 1,
                        "mean": -1.0,
                        "standard_error": 0.1,
                        "difference": 0.0,
                        "difference_standard_error": 0.0,
                        "fold_scores": [-1.1, -0.9],
                    }
                ],
                "explanation": "ds = 1 is best.",
            },
        },
        "/trials": {
            "model_id": ids["model_id"],
            "mode": "scripted",
            "policy": "active",
            "max_steps": 3,
            "tolerance": 0.001,
            "confidence_threshold": 0.9,
            "prior_mean": [0.0, 0.0],
            "prior_cov": [[1.0, 0.0], [0.0, 1.0]],
            "action_bounds": {"lower": [-2.0], "upper": [2.0]},
            "fixed_action": [0.5],
            "target": "O1",
            "target_slot": 1,
            "seed": 3,
            "simulation": {
                "world": "experiment1",
                "noise_std": 0.1,
                "world_seed": 0,
                "step_interval_s": 0.0,
            },
        },
        "/trials/{trial_id}/observations": {
            "action": [0.5],
            "observation": [0.1, 0.2, 0.3],
            "trajectory": {"waypoints_deg": [[0.0, 1.0]], "note": "x"},
        },
        "/rig/turntable": {"slot": 1},
        "/collections": {
            "name": "c",
            "objects": [{"name": "A", "slot": 0}, {"name": "B", "slot": 1}],
            "samples_per_object": 2,
            "action_design": "random",
            "action_scale": 1.0,
            "seed": 1,
        },
        "/evaluations": {
            "model_id": ids["model_id"],
            "world": "exp1",
            "dataset_id": ids["dataset_id"],
            "targets": ["O1"],
            "policies": ["active"],
            "trials_per_target": 1,
            "steps": 2,
            "confidence": 0.9,
            "seed": 0,
            "table": "t",
            "placement": "trial",
            "workers": 1,
        },
        "/session": {"token": "not the token"},
    }


def operations(client: TestClient) -> list[tuple[str, str, bool]]:
    """(method, path template after /api/v1, takes a body) of every POST/PUT/PATCH route; a
    control route (``{action}``) once with each action."""
    schema = client.get(f"{API}/openapi.json").json()
    found = []
    for path, items in schema["paths"].items():
        for method, operation in items.items():
            if method in ("post", "put", "patch"):
                for action in get_args(Action) if "{action}" in path else ("{action}",):
                    concrete = path.removeprefix(API).replace("{action}", action)
                    found.append((method, concrete, "requestBody" in operation))
    return found


def leaf_paths(value: Any, prefix: tuple[str | int, ...] = ()) -> Iterator[tuple[str | int, ...]]:
    """Every field of a JSON value (a list: itself and its first item, recursively)."""
    if prefix:
        yield prefix
    if isinstance(value, dict):
        for key, item in value.items():
            yield from leaf_paths(item, (*prefix, key))
    elif isinstance(value, list) and value:
        yield from leaf_paths(value[0], (*prefix, 0))


def with_raw_value(body: Any, path: tuple[str | int, ...], raw: bytes) -> bytes:
    """``body`` as JSON bytes with the field at ``path`` replaced by the raw JSON ``raw``."""
    copy = json.loads(json.dumps(body))
    target = copy
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = _SLOT
    return json.dumps(copy).encode().replace(json.dumps(_SLOT).encode(), raw)


def refusal_problem(response: Any, what: str) -> str | None:
    """What is wrong with the answer to a request the API cannot serve (None: a 4xx with a
    JSON ``detail``, as it should be)."""
    if not 400 <= response.status_code < 500:
        return f"{what}: {response.status_code} {response.text[:200]}"
    body = response.json()
    if not (isinstance(body, dict) and body.get("detail")):
        return f"{what}: no detail in {body!r:.200}"
    return None


def send(client: TestClient, method: str, url: str, content_type: str | None, body: bytes) -> Any:
    headers = {} if content_type is None else {"content-type": content_type}
    return client.request(method, url, content=body, headers=headers)


def test_the_sweep_covers_every_route_with_a_body(client: TestClient, ids: dict[str, int]) -> None:
    with_body = {path for _, path, has_body in operations(client) if has_body}
    assert with_body == set(example_bodies(ids)), "give every route with a body an example"


def test_the_examples_are_accepted(client: TestClient, ids: dict[str, int]) -> None:
    """Each example body is valid, so a refusal in the sweep is about the replaced field.

    (The rig is serial without ports, so rig routes answer 503; a server without a token
    answers a sign-in 409. The bodies that would start a fit or an evaluation in the
    background are checked against their schema only.)
    """
    for path, schema in (
        ("/models", ModelCreate),
        ("/trials", TrialCreate),
        ("/evaluations", EvaluationCreate),
    ):
        schema.model_validate(example_bodies(ids)[path])
    expected = {
        "/datasets": 201,
        "/models/import": 201,
        "/trials/{trial_id}/observations": 200,
        "/rig/turntable": 503,
        "/collections": 503,
        "/session": 409,
    }
    for path, status in expected.items():
        response = client.post(f"{API}{path.format(**ids)}", json=example_bodies(ids)[path])
        assert response.status_code == status, (path, response.text)


@pytest.mark.parametrize("case", sorted(BAD_BODIES))
def test_a_malformed_body_is_refused_with_a_detail(
    client: TestClient, ids: dict[str, int], case: str
) -> None:
    content_type, body = BAD_BODIES[case]
    problems = []
    for method, path, has_body in operations(client):
        path_ids = ids if has_body else {**ids, "trial_id": ids["spare_trial_id"]}
        response = send(client, method, f"{API}{path.format(**path_ids)}", content_type, body)
        what = f"{case} to {method.upper()} {path}"
        if has_body:
            problems.append(refusal_problem(response, what))
        elif response.status_code == 500:
            # No body expected: it is ignored; the route answers as it would anyway (503: the
            # rig has no ports).
            problems.append(f"{what}: {response.status_code} {response.text[:200]}")
    found = [problem for problem in problems if problem]
    assert not found, "\n".join(found)


@pytest.mark.parametrize("value", sorted(BAD_VALUES))
def test_every_field_with_a_bad_value_is_refused(
    client: TestClient, ids: dict[str, int], value: str
) -> None:
    observations = f"{API}/trials/{ids['trial_id']}/observations"
    valid = example_bodies(ids)["/trials/{trial_id}/observations"]
    assert client.post(observations, json=valid).status_code == 200, "the trial must be open"
    problems = []
    for path, example in example_bodies(ids).items():
        url = f"{API}{path.format(**ids)}"
        for field in leaf_paths(example):
            if field[0] == "trajectory" and value in WELL_FORMED_IN_A_RECORD:
                continue
            body = with_raw_value(example, field, BAD_VALUES[value])
            response = send(client, "post", url, "application/json", body)
            what = f"{value} in {'.'.join(map(str, field))} of POST {path}"
            problems.append(refusal_problem(response, what))
    found = [problem for problem in problems if problem]
    assert not found, "\n".join(found)


def test_a_chunked_body_over_the_limit_is_a_413(client: TestClient, ids: dict[str, int]) -> None:
    """Without a Content-Length the body is counted as it arrives; FastAPI's JSON reading must
    not turn the cut into a 400."""
    chunk = b" " * (256 * 1024)
    problems = []
    for method, path, has_body in operations(client):
        if not has_body:
            continue
        chunks = iter([b'{"name": "', *[chunk] * (UPLOAD_LIMIT_BYTES // len(chunk) + 1), b'"}'])
        response = client.request(
            method,
            f"{API}{path.format(**ids)}",
            content=chunks,
            headers={"content-type": "application/json"},
        )
        if response.status_code != 413 or response.json().get("limit_bytes") != UPLOAD_LIMIT_BYTES:
            problems.append(
                f"{method.upper()} {path}: {response.status_code} {response.text[:200]}"
            )
    assert not problems, "\n".join(problems)


def test_a_bug_is_a_logged_json_500(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """What no handler knows is a bug: logged with its traceback, answered with a JSON detail
    that says nothing of the internals."""
    app = create_app(make_settings(tmp_path))

    @app.get("/api/v1/broken")
    def broken() -> None:
        raise RuntimeError("secret internals")

    with TestClient(app, raise_server_exceptions=False) as test_client:
        response = test_client.get("/api/v1/broken")
    assert response.status_code == 500
    assert response.json() == {"detail": "Internal server error."}
    assert "secret internals" in caplog.text
