"""The app context: everything one app instance owns, built at start-up and closed at shutdown."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from app import crud
from app.config import Settings
from app.db import Database, upgrade_to_head
from app.services.collections import CollectionService
from app.services.evaluations import EvaluationService
from app.services.events import EventBus
from app.services.models import ModelStore
from app.services.rig import RigService
from app.services.runs import RunManager
from app.services.trial_views import TrialViews
from app.services.trials import TrialService
from app.services.worlds import WorldFactory

logger = logging.getLogger(__name__)

INTERRUPTED = "interrupted"


@dataclass
class AppContext:
    """Settings, database, event bus and the services that own background work."""

    settings: Settings
    database: Database
    events: EventBus
    models: ModelStore
    runs: RunManager
    trials: TrialService
    trial_views: TrialViews
    rig: RigService
    collections: CollectionService
    evaluations: EvaluationService

    def close(self) -> None:
        """Stop background work, close the rig and the database."""
        self.evaluations.close()
        self.runs.close()
        self.models.close()
        self.rig.close()
        self.database.dispose()


def start_context(settings: Settings) -> AppContext:
    """Open the database, migrate it to head, fail runs a previous process left running."""
    database = Database(settings.database_url)
    upgrade_to_head(database.engine, settings.migrations_dir)
    with database.session() as session:
        changed = crud.fail_interrupted(session, INTERRUPTED)
    events = EventBus(database, keep=settings.event_log_size)
    for kind, ids in changed.items():
        for item_id in ids:
            logger.warning("%s %d was left running by a previous process: failed", kind, item_id)
            events.publish(
                f"{kind.rstrip('s')}.status",
                {f"{kind.rstrip('s')}_id": item_id, "status": "failed", "reason": INTERRUPTED},
            )
    models = ModelStore(database, events, max_training_touches=settings.max_training_touches)
    runs = RunManager()
    rig = RigService(settings, runs, events)
    trials = TrialService(settings, database, events, models, runs, WorldFactory(rig), rig)
    return AppContext(
        settings=settings,
        database=database,
        events=events,
        models=models,
        runs=runs,
        trials=trials,
        trial_views=TrialViews(),
        rig=rig,
        collections=CollectionService(database, events, runs, rig),
        evaluations=EvaluationService(settings, database, events, models),
    )
