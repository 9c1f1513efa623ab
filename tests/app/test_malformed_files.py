"""A training CSV or model document that cannot be used is refused with where and why: 422
naming row and column from the API (CSV body and multipart upload alike), exit 2 with a one-line
message from the CLI — never a 500 or a traceback."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from app.cli.main import app as cli
from app.documents.training_csv import MAX_NAME_CHARACTERS
from app.main import create_app
from tests.app.conftest import TestClient, make_settings

API = "/api/v1"
GOOD_ROWS = "A,0.1,0.2\nA,0.3,0.4\nB,0.5,0.6\nB,0.7,0.8\n"
HEADER = "object,x_1,y_1\n"

#: A CSV that cannot be used → (row, column) the refusal names (row 1 is the header).
BAD_CSV: dict[str, tuple[str, int, str | None]] = {
    "a name over the csv module's field limit": (
        HEADER + GOOD_ROWS + "N" * 200_000 + ",1,2\n",
        6,
        "object",
    ),
    "a number over the field limit": (HEADER + GOOD_ROWS + "A,1," + "1" * 200_000 + "\n", 6, "y_1"),
    "a header over the field limit": ("object,x_1," + "y" * 200_000 + "\n" + GOOD_ROWS, 1, None),
    "a name over the name limit": (
        HEADER + "N" * (MAX_NAME_CHARACTERS + 1) + ",1,2\n" + GOOD_ROWS,
        2,
        "object",
    ),
    "NaN": (HEADER + GOOD_ROWS + "A,NaN,2\n", 6, "x_1"),
    "1e400": (HEADER + GOOD_ROWS + "A,1,1e400\n", 6, "y_1"),
    "-inf": (HEADER + "A,-inf,2\n" + GOOD_ROWS, 2, "x_1"),
    "a word for a number": (HEADER + GOOD_ROWS + "A,one,2\n", 6, "x_1"),
    "a ragged row": (HEADER + GOOD_ROWS + "A,1\n", 6, None),
    "an empty name": (HEADER + " ,1,2\n" + GOOD_ROWS, 2, "object"),
    "an unknown column": ("object,x_1,z_1\n" + GOOD_ROWS, 1, "z_1"),
    "no data rows": (HEADER, 2, None),
}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = make_settings(tmp_path_factory.mktemp("malformed-files"), hardware="serial")
    with TestClient(create_app(settings), raise_server_exceptions=False) as test_client:
        yield test_client


def test_the_good_rows_are_a_dataset(client: TestClient) -> None:
    """The rows the bad files add to are accepted on their own (so the refusals are about the
    bad line)."""
    response = client.post(
        f"{API}/datasets", content=HEADER + GOOD_ROWS, headers={"content-type": "text/csv"}
    )
    assert response.status_code == 201, response.text


@pytest.mark.parametrize("case", sorted(BAD_CSV))
@pytest.mark.parametrize("upload", ["text/csv", "multipart"])
def test_a_bad_csv_upload_is_a_422_naming_row_and_column(
    client: TestClient, case: str, upload: str
) -> None:
    text, row, column = BAD_CSV[case]
    if upload == "multipart":
        response = client.post(f"{API}/datasets", files={"file": ("touches.csv", text)})
    else:
        response = client.post(
            f"{API}/datasets", content=text, headers={"content-type": "text/csv"}
        )
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["row"] == row, body
    assert body.get("column") == column, body
    assert body["detail"].startswith("CSV")
    assert len(response.content) < 2000, "the refusal quotes the file shortly"


@pytest.mark.parametrize(
    ("upload", "field"),
    [("text/csv", "body"), ("multipart", "file")],
)
def test_a_csv_that_is_not_utf8_is_a_422(client: TestClient, upload: str, field: str) -> None:
    raw = (HEADER + GOOD_ROWS).encode() + b"A,\xff,1\n"
    if upload == "multipart":
        response = client.post(f"{API}/datasets", files={"file": ("touches.csv", raw)})
    else:
        response = client.post(f"{API}/datasets", content=raw, headers={"content-type": "text/csv"})
    assert response.status_code == 422, response.text
    assert response.json()["field"] == field
    assert "not UTF-8" in response.json()["detail"]


def test_a_scripted_nan_observation_is_a_422_quoting_it(client: TestClient) -> None:
    """The case a user found: the refusal quotes the NaN it refuses (as a string)."""
    response = client.post(
        f"{API}/trials/1/observations",
        content=b'{"action": [0.5], "observation": [NaN, 1.0]}',
        headers={"content-type": "application/json"},
    )
    assert response.status_code == 422, response.text
    (error,) = response.json()["detail"]
    assert error["loc"] == ["body", "observation", 0]
    assert error["input"] == "NaN"


@pytest.mark.parametrize("case", ["a name over the csv module's field limit", "NaN", "1e400"])
def test_fit_refuses_a_bad_csv_with_exit_2_and_the_row(tmp_path: Path, case: str) -> None:
    text, row, column = BAD_CSV[case]
    path = tmp_path / "touches.csv"
    path.write_text(text)
    result = CliRunner().invoke(cli, ["fit", str(path), "--latent-dim", "1"])
    assert result.exit_code == 2, result.output
    assert f"row {row}, column {column}" in result.output
    assert "Traceback" not in result.output


def test_fit_refuses_a_file_that_is_not_utf8_with_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "touches.csv"
    path.write_bytes((HEADER + GOOD_ROWS).encode() + b"A,\xff,1\n")
    result = CliRunner().invoke(cli, ["fit", str(path), "--latent-dim", "1"])
    assert result.exit_code == 2, result.output
    assert "not UTF-8" in result.output


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ('{"format": NaN}', "format is a non-finite number"),
        ('{"a": ' + "9" * 5000 + "}", "digit"),
    ],
)
def test_recognize_refuses_a_bad_model_document_with_exit_2(
    tmp_path: Path, content: str, message: str
) -> None:
    path = tmp_path / "model.json"
    path.write_text(content)
    result = CliRunner().invoke(cli, ["recognize", "--model", str(path), "--target", "O1"])
    assert result.exit_code == 2, result.output
    assert message in result.output


def test_dataset_into_a_missing_folder_is_exit_2(tmp_path: Path) -> None:
    out = tmp_path / "missing" / "touches.csv"
    result = CliRunner().invoke(cli, ["dataset", "exp1", "--out", str(out), "--touches", "2"])
    assert result.exit_code == 2, result.output
    assert "--out: cannot write" in result.output
    assert not out.exists()


def test_every_refusal_is_strict_json(client: TestClient) -> None:
    """The bodies parse with a strict JSON parser (no NaN/Infinity tokens)."""
    response = client.post(
        f"{API}/trials",
        content=b'{"model_id": 1, "mode": "scripted", "prior_mean": [Infinity, -Infinity, NaN]}',
        headers={"content-type": "application/json"},
    )
    assert response.status_code == 422
    json.loads(response.text, parse_constant=lambda token: pytest.fail(f"{token} in the body"))
