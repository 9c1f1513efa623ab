"""Models: read, keep fitted ones for use, export and import documents (fits are jobs of
:mod:`app.services.fits`).

The GP posterior is not stored, only how it was conditioned (the row's ``posterior``: the model
document's ``posterior`` field, :func:`app.documents.posterior.posterior_field`).
:class:`ReadyModels` rebuilds a :class:`ManifoldModel` from the dataset, latents, hyperparameters
and that record (deterministic, :func:`app.documents.posterior.condition_as_recorded`), so a
model predicts the same after it leaves the in-memory cache of recent ones. Rows from before the
record existed (``posterior`` NULL) are rebuilt as :func:`core.gp.posterior.condition` chooses by
default, as they were then."""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections import OrderedDict
from collections.abc import Callable
from functools import partial
from typing import Any, get_args

import numpy as np
from pydantic import ValidationError
from sqlalchemy.orm import Session

from app import crud
from app.db import Database
from app.db.tables import ModelRecord, utc_now
from app.documents.errors import DocumentError
from app.documents.features import features_field, read_features_field
from app.documents.model import (
    calibration_fields,
    model_from_document,
    model_to_document,
    placement_in_fit_variance,
    read_calibrations,
)
from app.documents.noise_model import noise_model_field, read_noise_model_field
from app.documents.posterior import condition_as_recorded, posterior_field
from app.errors import AppError, BadInputError, ConflictError
from app.schemas import (
    FeatureHyperparameters,
    FeaturesPublic,
    LatentSelectionPublic,
    LatentUncertaintyPublic,
    ModelPosterior,
    ModelPublic,
    NoiseModelPublic,
    ObjectLatent,
    Page,
    PlacementEffectPublic,
)
from app.services import datasets
from app.services.events import EventBus
from app.states import ModelStatus
from core.errors import CoreError
from core.types import FitDiagnostics, Hyperparameters, ManifoldModel

logger = logging.getLogger(__name__)


class StoredModelError(AppError):
    """A ready model's row cannot be rebuilt (a malformed posterior record, or data that no
    longer fit it): the database was changed behind the server's back (500)."""

    status_code = 500


#: Key of a model row's posterior record: its training y are its pipeline's features of the
#: dataset's raw touches.
FEATURISED = "featurised_from_raw"


def observation_dim(row: ModelRecord) -> int:
    """dy of a model: its fitted features (a pipeline may make another dy than the dataset's
    stored y), else its dataset's."""
    if row.signal_variance is not None:
        return int(row.signal_variance.shape[0])
    return int(row.dataset.observation_dim)


def _diagnostics_dict(diagnostics: FitDiagnostics | None) -> dict[str, Any] | None:
    if diagnostics is None:
        return None
    return {
        "starts_log_likelihood": [float(v) for v in diagnostics.starts_log_likelihood],
        "best_start": int(diagnostics.best_start),
        "iterations": int(diagnostics.iterations),
        "converged": bool(diagnostics.converged),
        "message": str(diagnostics.message),
        "jitter_used": float(diagnostics.jitter_used),
        "hyperparameters_at_bounds": list(diagnostics.hyperparameters_at_bounds),
        "kernels": diagnostics.kernels,
    }


def _diagnostics_from_dict(values: dict[str, Any] | None) -> FitDiagnostics | None:
    if values is None:
        return None
    return FitDiagnostics(
        starts_log_likelihood=tuple(values["starts_log_likelihood"]),
        best_start=values["best_start"],
        iterations=values["iterations"],
        converged=values["converged"],
        message=values["message"],
        jitter_used=values["jitter_used"],
        hyperparameters_at_bounds=tuple(values["hyperparameters_at_bounds"]),
        kernels=str(values.get("kernels", "per_feature")),  # rows stored before tied kernels
    )


def store_fitted(
    row: ModelRecord,
    model: ManifoldModel,
    fit_seconds: float | None,
    latent_selection: dict[str, Any] | None = None,
    featurised: bool = False,
) -> None:
    """Copy a fitted model's latents, hyperparameters, posterior record
    (:func:`app.documents.posterior.posterior_field`, with the observation transform under
    ``noise_model``, the feature pipeline under ``features`` and the calibration fields —
    ``placement_effect``, ``latent_uncertainty``, ``tempering`` — as the model document has
    them, :func:`app.documents.model.calibration_fields`), diagnostics (with
    ``latent_selection`` when ds was chosen) into its row; mark ready.

    ``featurised``: the model's y were made by its pipeline from the dataset's raw touches (not
    the y stored with the dataset); recorded as ``featurised_from_raw``, so that
    :meth:`ReadyModels.load` makes them again the same way."""
    h = model.hyperparameters
    row.latent_dim = model.latent_dim
    row.latents = model.latents
    record = posterior_field(model.posterior)
    noise = noise_model_field(model.transform)
    if noise is not None:
        record["noise_model"] = noise
    if model.features is not None:
        record["features"] = features_field(model.features)
        if featurised:
            record[FEATURISED] = True
    record.update(calibration_fields(model))
    row.posterior = record
    row.signal_variance = h.signal_variance
    row.noise_variance = h.noise_variance
    row.latent_lengthscales = h.latent_lengthscales
    row.action_lengthscales = h.action_lengthscales
    row.log_likelihood = float(model.log_likelihood)
    diagnostics = _diagnostics_dict(model.diagnostics)
    if latent_selection is not None:
        diagnostics = {**(diagnostics or {}), "latent_selection": latent_selection}
    row.diagnostics = diagnostics
    row.fit_seconds = fit_seconds
    row.status = "ready"
    row.finished_at = utc_now()


def _noise_model_public(row: ModelRecord) -> NoiseModelPublic | None:
    if row.status != "ready":
        return None
    field = row.posterior.get("noise_model") if isinstance(row.posterior, dict) else None
    dy = observation_dim(row)
    try:
        transform = read_noise_model_field(field, dy, where="model row")
    except DocumentError:  # changed behind the server's back; load() says so (500)
        logger.warning("model %d: malformed noise_model record %r", row.id, field)
        return None
    if transform is None:
        eye = np.eye(dy)
        return NoiseModelPublic(
            kind="identity",
            correlation=eye.tolist(),
            scale=[1.0] * dy,
            note="observations used as recorded (fitted before noise models existed)",
        )
    return NoiseModelPublic(
        kind=transform.kind,
        correlation=transform.correlation.tolist(),
        scale=transform.scale.tolist(),
        note=transform.note,
    )


def _features_public(row: ModelRecord) -> FeaturesPublic | None:
    field = row.posterior.get("features") if isinstance(row.posterior, dict) else None
    if field is None:
        return None
    try:
        pipeline = read_features_field(field, observation_dim(row))
    except DocumentError:  # changed behind the server's back; load() says so (500)
        logger.warning("model %d: malformed features record", row.id)
        return None
    assert pipeline is not None
    return FeaturesPublic(
        kind=pipeline.kind,
        channels=[p.name for p in pipeline.channels],
        reduced_features=len(pipeline.reduced_names),
        projection=pipeline.projection if pipeline.kind == "whole" else None,
        output_names=list(pipeline.output_names),
        explanation=None if pipeline.selection is None else pipeline.selection.explanation,
    )


def _latent_uncertainty_public(row: ModelRecord) -> LatentUncertaintyPublic | None:
    field = row.posterior.get("latent_uncertainty") if isinstance(row.posterior, dict) else None
    if field is None or row.status != "ready":
        return None
    try:
        covariance = np.asarray(field["covariance"], dtype=np.float64)
        std = np.sqrt(np.diagonal(covariance, axis1=1, axis2=2))
    except (KeyError, TypeError, ValueError):  # changed behind the server's back; load() says so
        logger.warning("model %d: malformed latent_uncertainty record %r", row.id, field)
        return None
    return LatentUncertaintyPublic(std=std.tolist())


def _placement_effect_public(row: ModelRecord) -> PlacementEffectPublic | None:
    field = row.posterior.get("placement_effect") if isinstance(row.posterior, dict) else None
    if field is None or row.status != "ready" or row.noise_variance is None:
        return None
    try:
        variance = np.asarray(field["variance"], dtype=np.float64)
        ratio = variance / row.noise_variance
        rows = field.get("by_object")
        by_object = None if rows is None else np.asarray(rows, dtype=np.float64).tolist()
    except (KeyError, TypeError, ValueError):  # changed behind the server's back; load() says so
        logger.warning("model %d: malformed placement_effect record %r", row.id, field)
        return None
    return PlacementEffectPublic(
        variance=variance.tolist(),
        noise_ratio=ratio.tolist(),
        in_training_covariance=field.get("in_training_covariance") is True,
        by_object=by_object,
    )


def _latent_selection_public(row: ModelRecord) -> LatentSelectionPublic | None:
    values = row.diagnostics.get("latent_selection") if row.diagnostics else None
    if values is None:
        return None
    try:
        return LatentSelectionPublic.model_validate(values)
    except ValidationError:
        logger.warning("model %d: malformed latent_selection %r", row.id, values)
        return None


def to_public(row: ModelRecord, queue_position: int | None = None) -> ModelPublic:
    """The API view of a model row (``queue_position``: its place in the queue of fits)."""
    objects: list[ObjectLatent] = []
    hyper: list[FeatureHyperparameters] = []
    if row.latents is not None:
        objects = [
            ObjectLatent(name=name, latent=latent.tolist())
            for name, latent in zip(row.dataset.object_names, row.latents, strict=True)
        ]
    if (
        row.signal_variance is not None
        and row.noise_variance is not None
        and row.latent_lengthscales is not None
        and row.action_lengthscales is not None
    ):
        hyper = [
            FeatureHyperparameters(
                feature=a,
                signal_variance=float(row.signal_variance[a]),
                noise_variance=float(row.noise_variance[a]),
                latent_lengthscales=row.latent_lengthscales[a].tolist(),
                action_lengthscales=row.action_lengthscales[a].tolist(),
            )
            for a in range(row.signal_variance.shape[0])
        ]
    status = row.status if row.status in get_args(ModelStatus) else "failed"
    posterior: ModelPosterior | None = None
    if row.posterior is not None:
        try:
            posterior = ModelPosterior.model_validate(row.posterior)
        except ValidationError:  # changed behind the server's back; load() says so (500)
            logger.warning("model %d: malformed posterior record %r", row.id, row.posterior)
    return ModelPublic(
        id=row.id,
        status=status,
        queue_position=queue_position,
        reason=row.reason,
        dataset_id=row.dataset_id,
        latent_dim=row.latent_dim,
        action_dim=row.dataset.action_dim,
        observation_dim=observation_dim(row),
        optimizer=row.optimizer,
        restarts=row.restarts,
        seed=row.seed,
        objects=objects,
        log_likelihood=row.log_likelihood,
        hyperparameters=hyper,
        fit_seconds=row.fit_seconds,
        diagnostics=row.diagnostics,
        progress=row.progress,
        posterior=posterior,
        noise_model=_noise_model_public(row),
        latent_selection=_latent_selection_public(row),
        features=_features_public(row),
        placement_effect=_placement_effect_public(row),
        latent_uncertainty=_latent_uncertainty_public(row),
        created_at=row.created_at,
        finished_at=row.finished_at,
    )


require = partial(crud.require, ModelRecord)


def get(session: Session, model_id: int) -> ModelPublic:
    """One model (without its place in a queue: see :meth:`app.services.fits.FitService.get`)."""
    return to_public(require(session, model_id))


def list_page(
    session: Session,
    status: str | None,
    limit: int,
    offset: int,
    queue_position: Callable[[int], int | None] | None = None,
) -> Page[ModelPublic]:
    """Models, newest first (``queue_position``: a model's place in the queue of fits)."""
    rows, count = crud.list_models(session, status, limit, offset)

    def position(row: ModelRecord) -> int | None:
        if queue_position is None or row.status != "queued":
            return None
        return queue_position(row.id)

    return Page[ModelPublic](
        data=[to_public(r, position(r)) for r in rows],
        count=count,
    )


class ReadyModels:
    """The ready models: rebuilt from their rows for use (the recent ones cached), exported and
    imported as model documents. Fitting is elsewhere (:class:`app.services.fits.FitService`).

    Args:
        database: Where models live.
        events: Where imports are announced.
        max_training_touches: Largest N accepted for a fit or an imported document.
        cache_size: How many rebuilt models are kept in memory.
    """

    def __init__(
        self,
        database: Database,
        events: EventBus,
        max_training_touches: int = 5000,
        cache_size: int = 8,
    ) -> None:
        self._database = database
        self._events = events
        self._max_touches = max_training_touches
        self._cache: OrderedDict[int, ManifoldModel] = OrderedDict()
        self._cache_size = cache_size
        self._lock = threading.Lock()

    def check_size(self, n_touches: int, field: str) -> None:
        """Refuse (422 naming ``field``) more touches than this server fits."""
        if n_touches > self._max_touches:
            raise BadInputError(
                f"{field}: {n_touches} touches is more than this server fits "
                f"({self._max_touches}); subsample the data.",
                field=field,
            )

    # --- use ----------------------------------------------------------------------------------

    def remember(self, model_id: int, model: ManifoldModel) -> None:
        """Keep a fitted model for use (the least recently kept of too many is dropped)."""
        with self._lock:
            self._cache[model_id] = model
            self._cache.move_to_end(model_id)
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)

    def load(self, session: Session, model_id: int) -> ManifoldModel:
        """The fitted model, ready to predict and plan.

        Raises:
            NotFoundError: No such model.
            ConflictError: The model is still fitting or failed.
        """
        with self._lock:
            cached = self._cache.get(model_id)
        if cached is not None:
            return cached
        row = require(session, model_id)
        if row.status != "ready":
            raise ConflictError(
                f"Model {model_id} is {row.status}; only a ready model can be used.",
                current_state=row.status,
            )
        record = row.posterior if isinstance(row.posterior, dict) else {}
        try:
            pipeline = read_features_field(record.get("features"), observation_dim(row))
        except DocumentError as exc:
            raise StoredModelError(
                f"Model {model_id} cannot be rebuilt from what is stored: {exc}",
                model_id=model_id,
            ) from exc
        if pipeline is not None and record.get(FEATURISED):
            data = datasets.featurised_data(session, row.dataset_id, pipeline)
        else:
            data = datasets.training_data(session, row.dataset_id)
        assert row.latents is not None
        assert row.signal_variance is not None
        assert row.noise_variance is not None
        assert row.latent_lengthscales is not None
        assert row.action_lengthscales is not None
        hyper = Hyperparameters(
            signal_variance=row.signal_variance,
            noise_variance=row.noise_variance,
            latent_lengthscales=row.latent_lengthscales,
            action_lengthscales=row.action_lengthscales,
        )
        try:
            noise = row.posterior.get("noise_model") if isinstance(row.posterior, dict) else None
            model = condition_as_recorded(
                data,
                row.latents,
                hyper,
                _diagnostics_from_dict(row.diagnostics),
                row.posterior,
                where="model row",
                transform=read_noise_model_field(noise, data.observation_dim, where="model row"),
                placement_variance=placement_in_fit_variance(record, "model row"),
            )
            if pipeline is not None:
                model = dataclasses.replace(model, features=pipeline)
            model = read_calibrations(record, model)
        except (CoreError, ValueError, KeyError, TypeError) as exc:
            raise StoredModelError(
                f"Model {model_id} cannot be rebuilt from what is stored: "
                f"{type(exc).__name__}: {exc}",
                model_id=model_id,
            ) from exc
        self.remember(model_id, model)
        return model

    def export_document(self, session: Session, model_id: int) -> dict[str, Any]:
        """The model document (``activetouch-model/1``) of a ready model."""
        model = self.load(session, model_id)
        row = require(session, model_id)
        selection = row.diagnostics.get("latent_selection") if row.diagnostics else None
        return model_to_document(model, fit_seconds=row.fit_seconds, latent_selection=selection)

    def import_document(self, session: Session, document: dict[str, Any]) -> ModelPublic:
        """Store a model document as a new dataset (source ``import``) and a ready model.

        Raises:
            BadInputError: The document is malformed (the message names the field).
        """
        training = document.get("training_data")
        if isinstance(training, dict) and isinstance(training.get("actions"), list):
            self.check_size(len(training["actions"]), "training_data.actions")
        try:
            model = model_from_document(document)
        except DocumentError:
            raise
        except (TypeError, ValueError, KeyError, AttributeError, OverflowError) as exc:
            raise BadInputError(f"model document: malformed ({exc})", field="document") from exc
        fit_seconds = document.get("fit_seconds")
        dataset = datasets.store_training_data(
            session,
            model.raw_data,
            name=str(document.get("name", "imported model"))[:200],
            source="import",
        )
        row = crud.create_model(
            session,
            dataset_id=dataset.id,
            status="fitting",
            latent_dim=model.latent_dim,
            optimizer="import",
            restarts=0,
            seed=None,
        )
        selection = document.get("latent_selection")
        store_fitted(
            row,
            model,
            float(fit_seconds) if isinstance(fit_seconds, int | float) else None,
            selection if isinstance(selection, dict) else None,
        )
        session.commit()
        self.remember(row.id, model)
        self._events.publish("model.status", {"model_id": row.id, "status": "ready"})
        session.refresh(row)
        return to_public(row)
