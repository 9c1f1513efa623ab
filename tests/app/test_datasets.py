"""Dataset upload (CSV body, multipart, JSON), validation errors, export round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app import crud
from app.documents.errors import DocumentError
from app.documents.training_csv import read_training_csv
from tests.app.conftest import experiment1_csv

CSV_HEADERS = {"content-type": "text/csv"}


def test_csv_upload_and_exact_export(client: TestClient) -> None:
    text = experiment1_csv(seed=3)
    response = client.post("/api/v1/datasets", content=text, headers=CSV_HEADERS)
    assert response.status_code == 201, response.text
    body = response.json()
    assert body["objects"] == ["O1", "O2", "O3", "O4"]
    assert (body["n_samples"], body["action_dim"], body["observation_dim"]) == (48, 1, 3)
    exported = client.get(f"/api/v1/datasets/{body['id']}/export?format=csv")
    assert exported.status_code == 200
    assert exported.headers["content-type"].startswith("text/csv")
    # Floats are written with repr: the export is the upload, byte for byte.
    assert exported.text == text
    assert client.get(f"/api/v1/datasets/{body['id']}").json() == body


def test_multipart_upload(client: TestClient) -> None:
    text = experiment1_csv(seed=4, touches_per_object=3)
    response = client.post(
        "/api/v1/datasets",
        files={"file": ("touches.csv", text.encode(), "text/csv")},
        data={"name": "bench run"},
    )
    assert response.status_code == 201, response.text
    assert response.json()["name"] == "bench run"
    assert response.json()["n_samples"] == 12


def test_json_upload_and_export(client: TestClient) -> None:
    samples = [
        {"object": name, "action": [0.1 * i, 1.0 / 3.0], "observation": [i + 0.5]}
        for name in ("cork", "steel")
        for i in range(3)
    ]
    response = client.post("/api/v1/datasets", json={"name": "j", "samples": samples})
    assert response.status_code == 201, response.text
    dataset_id = response.json()["id"]
    exported = client.get(f"/api/v1/datasets/{dataset_id}/export?format=json").json()
    assert exported["samples"] == samples
    listing = client.get("/api/v1/datasets").json()
    assert listing["count"] == 1
    assert listing["data"][0]["id"] == dataset_id


@pytest.mark.parametrize(
    ("text", "row", "column"),
    [
        ("object,x_1,y_1\na,1,2\na,2,nan\nb,1,1\nb,2,2\n", 3, "y_1"),
        ("object,x_1,y_1\na,1,2\na,2,inf\nb,1,1\nb,2,2\n", 3, "y_1"),
        ("object,x_1,y_1\na,1,2\na,2\nb,1,1\nb,2,2\n", 3, None),
        ("object,x_1,z_1\na,1,2\n", 1, "z_1"),
        ("object,x_1,y_1\na,1,2\na,2,abc\n", 3, "y_1"),
    ],
)
def test_bad_csv_names_row_and_column(
    client: TestClient, text: str, row: int, column: str | None
) -> None:
    response = client.post("/api/v1/datasets", content=text, headers=CSV_HEADERS)
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["row"] == row
    assert body.get("column") == column
    assert (f"row {row}" if row > 1 else "header") in body["detail"]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("object,x_1,y_1\na,1,2\na,2,3\n", "at least 2 objects"),
        ("object,x_1,y_1\na,1,2\na,2,3\nb,1,1\n", "'b' has 1 touch"),
    ],
)
def test_csv_too_few_objects_or_touches(client: TestClient, text: str, needle: str) -> None:
    response = client.post("/api/v1/datasets", content=text, headers=CSV_HEADERS)
    assert response.status_code == 422
    assert needle in response.json()["detail"]


def test_json_errors_name_the_field(client: TestClient) -> None:
    ragged = {
        "samples": [
            {"object": "a", "action": [1.0], "observation": [1.0]},
            {"object": "a", "action": [1.0, 2.0], "observation": [1.0]},
            {"object": "b", "action": [1.0], "observation": [1.0]},
            {"object": "b", "action": [1.0], "observation": [1.0]},
        ]
    }
    response = client.post("/api/v1/datasets", json=ragged)
    assert response.status_code == 422
    assert response.json()["field"] == "samples[1].action"
    nan_body = '{"samples": [{"object": "a", "action": [NaN], "observation": [1]}]}'
    response = client.post(
        "/api/v1/datasets", content=nan_body, headers={"content-type": "application/json"}
    )
    assert response.status_code == 422
    assert response.json()["errors"][0]["loc"] == ["samples", 0, "action", 0]
    response = client.post(
        "/api/v1/datasets", content=b"{not json", headers={"content-type": "application/json"}
    )
    assert response.status_code == 422


def test_unsupported_media_type_and_unknown_dataset(client: TestClient) -> None:
    response = client.post(
        "/api/v1/datasets", content=b"<xml/>", headers={"content-type": "application/xml"}
    )
    assert response.status_code == 415
    assert client.get("/api/v1/datasets/999").status_code == 404
    assert client.get("/api/v1/datasets/999/export").status_code == 404


def test_upload_size_limit(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from app.main import create_app
    from tests.app.conftest import make_settings

    app = create_app(make_settings(tmp_path, max_upload_bytes=2048))
    with TestClient(app) as small:
        big = experiment1_csv(seed=1, touches_per_object=40)
        assert len(big) > 2048
        response = small.post("/api/v1/datasets", content=big, headers=CSV_HEADERS)
        assert response.status_code == 413
        assert json.loads(response.text)["limit_bytes"] == 2048

        def chunks():  # no Content-Length: counted while read
            yield big[:1500].encode()
            yield big[1500:].encode()

        response = small.post("/api/v1/datasets", content=chunks(), headers=CSV_HEADERS)
        assert response.status_code == 413
        assert response.json()["limit_bytes"] == 2048


def test_a_partial_dataset_exports_in_the_same_format(client: TestClient) -> None:
    """A collection in progress (one object, one touch: not yet training data) exports its
    touches so far, in the training CSV format, floats exact."""
    context = client.app.state.context  # type: ignore[attr-defined]
    action, observation = np.array([0.1, -2.5e-7]), np.array([1 / 3, 7.0, -0.0])
    with context.database.session() as session:
        dataset = crud.create_dataset(
            session, name="partial", source="collection", status="collecting",
            object_names=["cup"], action_dim=2, observation_dim=3,
        )  # fmt: skip
        crud.add_samples(session, dataset, [("cup", action, observation, None, None, None)])
        session.commit()
        dataset_id = dataset.id
    exported = client.get(f"/api/v1/datasets/{dataset_id}/export?format=csv")
    assert exported.status_code == 200
    assert exported.text == f"object,x_1,x_2,y_1,y_2,y_3\ncup,0.1,-2.5e-07,{1 / 3!r},7.0,-0.0\n"
    with pytest.raises(
        DocumentError, match="at least 2 objects"
    ):  # one object: not training data yet
        read_training_csv(exported.text)
