"""Property-based test over the OpenAPI schema (schemathesis): no input gives a 500.

The app runs on a temporary database that already holds a dataset, a ready model and a
scripted trial with a step, so generated ids hit real rows as well as missing ones. 503/504
(device unavailable / timeout) are documented answers; only a 500 fails.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path

import schemathesis
from hypothesis import HealthCheck, settings

from app.main import create_app
from tests.app.conftest import TestClient, experiment1_csv, import_model, make_settings

_DIRECTORY = Path(tempfile.mkdtemp(prefix="activetouch-openapi-"))
atexit.register(shutil.rmtree, _DIRECTORY, ignore_errors=True)
# Serial hardware without ports: rig endpoints answer 503 at once instead of starting
# background collections on a simulated rig (they have their own tests).
_SETTINGS = make_settings(
    _DIRECTORY, max_upload_bytes=256 * 1024, max_training_touches=200, hardware="serial"
)


def _populate() -> None:
    with TestClient(create_app(_SETTINGS)) as client:
        client.post(
            "/api/v1/datasets", content=experiment1_csv(), headers={"content-type": "text/csv"}
        )
        model_id = import_model(client)
        trial = client.post(
            "/api/v1/trials",
            json={"model_id": model_id, "mode": "scripted", "target": "O1", "seed": 1},
        ).json()
        action = client.get(f"/api/v1/trials/{trial['id']}/next-action").json()["action"]
        client.post(
            f"/api/v1/trials/{trial['id']}/observations",
            json={"action": action, "observation": [0.1, 0.2, 0.3]},
        )


_populate()
APP = create_app(_SETTINGS)
schema = schemathesis.openapi.from_asgi("/api/v1/openapi.json", APP).exclude(path="/api/v1/events")


@schemathesis.check
def no_internal_server_error(
    ctx: schemathesis.CheckContext, response: schemathesis.Response, case: schemathesis.Case
) -> None:
    """500 means a bug; 503/504 (device unavailable / timeout) are answers the API documents.
    A refusal (4xx) says why in a JSON ``detail``."""
    if response.status_code == 500:
        raise AssertionError(f"500 Internal Server Error: {response.text[:500]}")
    if 400 <= response.status_code < 500:
        body = response.json()
        if not (isinstance(body, dict) and body.get("detail")):
            raise AssertionError(f"{response.status_code} without a detail: {response.text[:500]}")


@schema.parametrize()
@settings(
    max_examples=12,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    derandomize=True,
)
def test_no_input_gives_a_server_error(case: schemathesis.Case) -> None:
    case.call_and_validate(checks=[no_internal_server_error])
