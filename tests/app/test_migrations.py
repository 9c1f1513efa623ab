"""Alembic migrations: head matches the tables of :mod:`app.db.tables`; 0002 (``models.posterior``)
upgrades a database with models of revision 0001, which keep loading as before, and downgrades;
0006 (``samples.placement``) and 0007 (``samples.time_s``) likewise, and 0008
(``datasets.touch_duration_s``) without losing a sample of the parent table it changes.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import inspect, text

from app.db import Database, upgrade_to_head
from app.db.tables import Base, ModelRecord
from app.documents.model import model_to_document
from app.services.datasets import store_training_data, training_data
from app.services.events import EventBus
from app.services.models import ReadyModels
from core.evaluation.worlds import sample_experiment1
from core.gp.posterior import condition, predict
from tests.app.conftest import make_settings
from tests.app.posterior_cases import HYPER, LATENTS


def migrate(database: Database, migrations_dir: Path, revision: str, down: bool = False) -> None:
    config = Config()
    config.set_main_option("script_location", str(migrations_dir))
    with database.engine.begin() as connection:
        config.attributes["connection"] = connection
        (command.downgrade if down else command.upgrade)(config, revision)


def revision_of(database: Database) -> str | None:
    with database.engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def head_revision(migrations_dir: Path) -> str | None:
    """The newest revision of the migrations (later ones may follow 0002)."""
    config = Config()
    config.set_main_option("script_location", str(migrations_dir))
    return ScriptDirectory.from_config(config).get_current_head()


def model_columns(database: Database) -> set[str]:
    return {c["name"] for c in inspect(database.engine).get_columns("models")}


def test_head_matches_the_tables_of_the_app(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        assert revision_of(database) == head_revision(settings.migrations_dir)
        with database.engine.connect() as connection:
            assert compare_metadata(MigrationContext.configure(connection), Base.metadata) == []
    finally:
        database.dispose()


def test_models_of_revision_0001_upgrade_and_load_as_before(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    data = sample_experiment1(np.random.default_rng(3), touches_per_object=15)
    sparse = condition(data, LATENTS, HYPER, structure="sparse", n_inducing=9)
    auto = condition(data, LATENTS, HYPER)  # what a 0001 server rebuilt: dense at N = 60
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        store = ReadyModels(database, EventBus(database))
        with database.session() as session:
            document = json.loads(json.dumps(model_to_document(sparse)))
            model_id = store.import_document(session, document).id
        # Back to 0001 (the column goes, the row stays), then up again: the row has no record.
        migrate(database, settings.migrations_dir, "0001", down=True)
        assert revision_of(database) == "0001"
        assert "posterior" not in model_columns(database)
        with database.engine.connect() as connection:
            assert connection.execute(text("SELECT count(*) FROM models")).scalar() == 1
        migrate(database, settings.migrations_dir, "head")
        assert revision_of(database) == head_revision(settings.migrations_dir)
        assert "posterior" in model_columns(database)
        store = ReadyModels(database, EventBus(database))
        with database.session() as session:
            row = session.get(ModelRecord, model_id)
            assert row is not None
            assert row.status == "ready"
            assert row.posterior is None
            old = store.load(session, model_id)
    finally:
        database.dispose()
    assert old.posterior.structure == auto.posterior.structure == "dense"
    s, x = np.linspace(-1.5, 1.5, 5)[:, None], np.linspace(-2.0, 2.0, 5)[:, None]
    for left, right in zip(predict(old, s, x), predict(auto, s, x), strict=True):
        np.testing.assert_allclose(left, right, rtol=0.0, atol=1e-12)


@pytest.mark.parametrize(
    ("column", "field", "previous", "values"),
    [
        ("placement", "placement_index", "0005_evaluation_trial_refused", np.arange(12) % 2),
        ("time_s", "touch_times_s", "0006_sample_placement", 24.1 * np.arange(12) + 1 / 3),
    ],
    ids=["0006 placement", "0007 time"],
)
def test_a_samples_column_downgrades_and_upgrades(
    tmp_path: Path, column: str, field: str, previous: str, values: np.ndarray
) -> None:
    """Stored, then the revision that added the column undone (it goes, the samples stay) and
    redone (the column is back, NULL: the data no longer record it)."""
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    data = sample_experiment1(np.random.default_rng(4), touches_per_object=3)
    recorded = dataclasses.replace(data, **{field: values})
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        with database.session() as session:
            dataset_id = store_training_data(session, recorded, column, "upload").id
            session.commit()
        with database.session() as session:
            stored = getattr(training_data(session, dataset_id), field)
        assert stored is not None
        assert stored.tolist() == values.tolist()  # exact: float64 and integer columns
        migrate(database, settings.migrations_dir, previous, down=True)
        assert column not in sample_columns(database)
        with database.engine.connect() as connection:
            count = connection.execute(text("SELECT count(*) FROM samples")).scalar()
        assert count == data.n_touches
        migrate(database, settings.migrations_dir, "head")
        assert column in sample_columns(database)
        with database.session() as session:
            assert getattr(training_data(session, dataset_id), field) is None
    finally:
        database.dispose()


def sample_columns(database: Database) -> set[str]:
    return {c["name"] for c in inspect(database.engine).get_columns("samples")}


def test_the_datasets_duration_downgrades_and_upgrades_keeping_every_sample(
    tmp_path: Path,
) -> None:
    """``datasets`` is the parent of ``samples`` (ON DELETE CASCADE): undoing 0008 must change it
    in place, not drop and copy it (which, with foreign keys on, deletes every sample)."""
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    data = dataclasses.replace(
        sample_experiment1(np.random.default_rng(5), touches_per_object=3), touch_duration_s=8.5
    )
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        with database.session() as session:
            dataset_id = store_training_data(session, data, "timed", "upload").id
            session.commit()
        with database.session() as session:
            assert training_data(session, dataset_id).touch_duration_s == 8.5
        migrate(database, settings.migrations_dir, "0007_sample_time", down=True)
        assert "touch_duration_s" not in dataset_columns(database)
        with database.engine.connect() as connection:
            samples = connection.execute(text("SELECT count(*) FROM samples")).scalar()
            datasets = connection.execute(text("SELECT count(*) FROM datasets")).scalar()
        assert (samples, datasets) == (data.n_touches, 1)
        migrate(database, settings.migrations_dir, "head")
        with database.session() as session:
            again = training_data(session, dataset_id)
        assert again.touch_duration_s is None
        assert again.actions.tolist() == data.actions.tolist()
    finally:
        database.dispose()


def dataset_columns(database: Database) -> set[str]:
    return {c["name"] for c in inspect(database.engine).get_columns("datasets")}
