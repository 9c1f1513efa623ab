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
from app.services.fits import FitService
from app.services.jobs import JobRunner
from app.services.models import ReadyModels
from app.services.rig import RigService
from app.services.trial_views import TrialViews
from app.services.trials import TrialService
from app.services.worlds import WorldFactory
from app.states import INTERRUPTED

logger = logging.getLogger(__name__)


@dataclass
class AppContext:
    """Settings, database, event bus, the job runner and the services that start jobs on it."""

    settings: Settings
    database: Database
    events: EventBus
    jobs: JobRunner
    models: ReadyModels
    fits: FitService
    trials: TrialService
    trial_views: TrialViews
    rig: RigService
    collections: CollectionService
    evaluations: EvaluationService

    def close(self) -> None:
        """Stop every job (each ends ``failed`` "interrupted"), close the rig and the database."""
        self.jobs.close()
        self.rig.close()
        self.database.dispose()


def start_context(settings: Settings) -> AppContext:
    """Open the database, migrate it to head, fail the jobs a previous process left unfinished
    (:func:`app.crud.fail_interrupted`), and build the services on one job runner."""
    database = Database(settings.database_url)
    upgrade_to_head(database.engine, settings.migrations_dir)
    with database.session() as session:
        changed = crud.fail_interrupted(session, INTERRUPTED)
    events = EventBus(database, keep=settings.event_log_size)
    for kind, ids in changed.items():
        for item_id in ids:
            logger.warning("%s %d was left unfinished by a previous process: failed", kind, item_id)
            events.publish(
                f"{kind.rstrip('s')}.status",
                {f"{kind.rstrip('s')}_id": item_id, "status": "failed", "reason": INTERRUPTED},
            )
    jobs = JobRunner(limits={"fit": settings.max_concurrent_fits})
    models = ReadyModels(database, events, max_training_touches=settings.max_training_touches)
    rig = RigService(settings, jobs, events)
    trials = TrialService(settings, database, events, models, jobs, WorldFactory(rig), rig)
    return AppContext(
        settings=settings,
        database=database,
        events=events,
        jobs=jobs,
        models=models,
        fits=FitService(
            database,
            events,
            jobs,
            models,
            max_training_touches=settings.max_training_touches,
            scheduler=settings.dask_scheduler or None,
        ),
        trials=trials,
        trial_views=TrialViews(),
        rig=rig,
        collections=CollectionService(database, events, jobs, rig),
        evaluations=EvaluationService(settings, database, events, models, jobs),
    )
