"""CSV and model-document formats: round trips and errors that name what is wrong."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.documents.errors import DocumentError
from app.documents.model import model_from_document, model_to_document
from app.documents.training_csv import read_training_csv, write_training_csv
from core.evaluation.worlds import sample_experiment1
from core.gp.posterior import condition, predict
from core.types import Hyperparameters
from tests.app.posterior_cases import HYPER, LATENTS


@pytest.fixture
def data():
    return sample_experiment1(np.random.default_rng(3), touches_per_object=6)


def test_csv_round_trip_is_exact(data):
    again = read_training_csv(write_training_csv(data))
    assert again.object_names == data.object_names
    np.testing.assert_array_equal(again.object_index, data.object_index)
    np.testing.assert_array_equal(again.actions, data.actions)
    np.testing.assert_array_equal(again.observations, data.observations)


@pytest.mark.parametrize(
    ("text", "fragment", "row", "column"),
    [
        ("object,x_1,y_1,colour\na,1,2,3\n", "unknown column", 1, "colour"),
        ("thing,x_1,y_1\na,1,2\n", "first column must be 'object'", 1, "thing"),
        ("object,x_2,y_1\na,1,2\n", "expected object,x_1,y_1", 1, None),
        ("object,x_1,y_1\na,1,2\na,1\n", "row 3: has 2 fields", 3, None),
        ("object,x_1,y_1\na,1,2\nb,nan,2\n", "row 3, column x_1", 3, "x_1"),
        ("object,x_1,y_1\na,1,2\nb,1,inf\n", "row 3, column y_1", 3, "y_1"),
        ("object,x_1,y_1\na,1,abc\n", "row 2, column y_1: 'abc' is not a number", 2, "y_1"),
        ("object,x_1,y_1\n", "no data rows", 2, None),
        ("", "empty", 1, None),
    ],
)
def test_csv_errors_name_row_and_column(text, fragment, row, column):
    with pytest.raises(DocumentError, match=fragment) as info:
        read_training_csv(text)
    assert info.value.row == row
    assert info.value.column == column


def test_csv_needs_two_objects_with_two_touches():
    with pytest.raises(DocumentError, match="at least 2 objects"):
        read_training_csv("object,x_1,y_1\na,1,2\na,2,3\n")
    with pytest.raises(DocumentError, match="'b' has 1 touch"):
        read_training_csv("object,x_1,y_1\na,1,2\na,2,3\nb,1,1\n")


def test_model_document_round_trip_predicts_identically(data):
    model = condition(data, LATENTS, HYPER)
    document = json.loads(json.dumps(model_to_document(model, fit_seconds=1.5)))
    assert document["format"] == "activetouch-model/1"
    assert [o["name"] for o in document["objects"]] == list(data.object_names)
    again = model_from_document(document)
    assert again.log_likelihood == pytest.approx(model.log_likelihood, rel=1e-12)
    query_s = np.array([[0.1], [0.9]])
    query_x = np.array([[0.3], [-1.0]])
    for a, b in zip(
        predict(model, query_s, query_x), predict(again, query_s, query_x), strict=True
    ):
        np.testing.assert_array_equal(a, b)


def test_model_document_errors_name_the_field(data):
    hyper = Hyperparameters(np.ones(3), 0.1 * np.ones(3), np.ones((3, 1)), np.ones((3, 1)))
    document = model_to_document(condition(data, np.arange(4.0)[:, None], hyper))
    with pytest.raises(DocumentError, match="format must be"):
        model_from_document({**document, "format": "other"})
    broken = {k: v for k, v in document.items() if k != "hyperparameters"}
    with pytest.raises(DocumentError, match="missing field 'hyperparameters'"):
        model_from_document(broken)
    with pytest.raises(DocumentError, match="latent_dim is 2"):
        model_from_document({**document, "latent_dim": 2})
    bad_latent = json.loads(json.dumps(document))
    bad_latent["objects"][0]["latent"] = [float("nan")]
    with pytest.raises(DocumentError, match="non-finite"):
        model_from_document(bad_latent)


def test_model_document_malformed_diagnostics_is_a_document_error(data):
    hyper = Hyperparameters(np.ones(3), 0.1 * np.ones(3), np.ones((3, 1)), np.ones((3, 1)))
    document = model_to_document(condition(data, np.arange(4.0)[:, None], hyper))
    document["diagnostics"] = {"best_start": "first", "starts_log_likelihood": 3}
    with pytest.raises(DocumentError, match="diagnostics") as info:
        model_from_document(document)
    assert info.value.column == "diagnostics.starts_log_likelihood"
