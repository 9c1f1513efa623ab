"""Alembic migrations: head matches the tables of :mod:`app.db.tables`; 0002 (``models.posterior``)
upgrades a database with models of revision 0001, which keep loading as before, and downgrades;
0006 (``samples.placement``) and 0007 (``samples.time_s``) likewise.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
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


def test_samples_placement_of_revision_0006_downgrades_and_upgrades(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    data = sample_experiment1(np.random.default_rng(4), touches_per_object=3)
    placed = dataclasses.replace(data, placement_index=np.arange(data.n_touches) % 2)
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        with database.session() as session:
            dataset_id = store_training_data(session, placed, "placed", "upload").id
            session.commit()
        with database.session() as session:
            stored = training_data(session, dataset_id).placement_index
        np.testing.assert_array_equal(stored, placed.placement_index)
        # Back to 0005: the column goes, the samples stay; up again: their placements are NULL.
        migrate(database, settings.migrations_dir, "0005_evaluation_trial_refused", down=True)
        assert "placement" not in sample_columns(database)
        with database.engine.connect() as connection:
            count = connection.execute(text("SELECT count(*) FROM samples")).scalar()
        assert count == data.n_touches
        migrate(database, settings.migrations_dir, "head")
        assert "placement" in sample_columns(database)
        with database.session() as session:
            assert training_data(session, dataset_id).placement_index is None
    finally:
        database.dispose()


def test_samples_time_of_revision_0007_downgrades_and_upgrades(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    database = Database(settings.database_url)
    data = sample_experiment1(np.random.default_rng(4), touches_per_object=3)
    timed = dataclasses.replace(data, touch_times_s=24.1 * np.arange(data.n_touches) + 1 / 3)
    try:
        upgrade_to_head(database.engine, settings.migrations_dir)
        with database.session() as session:
            dataset_id = store_training_data(session, timed, "timed", "upload").id
            session.commit()
        with database.session() as session:
            stored = training_data(session, dataset_id).touch_times_s
        assert stored is not None
        assert stored.tolist() == timed.touch_times_s.tolist()  # exact: a float64 column
        # Back to 0006: the column goes, the samples stay; up again: their times are NULL.
        migrate(database, settings.migrations_dir, "0006_sample_placement", down=True)
        assert "time_s" not in sample_columns(database)
        with database.engine.connect() as connection:
            count = connection.execute(text("SELECT count(*) FROM samples")).scalar()
        assert count == data.n_touches
        migrate(database, settings.migrations_dir, "head")
        assert "time_s" in sample_columns(database)
        with database.session() as session:
            assert training_data(session, dataset_id).touch_times_s is None
    finally:
        database.dispose()


def sample_columns(database: Database) -> set[str]:
    return {c["name"] for c in inspect(database.engine).get_columns("samples")}
