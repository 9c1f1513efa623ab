"""Errors of the app and the one place that maps every package's errors to HTTP.

- :class:`NotFoundError` → 404, :class:`ConflictError` → 409 (with the current state),
  :class:`BadInputError` and :class:`core.errors.CoreError` → 422 (naming field, row, column),
  a device unavailable → 503, a device timeout → 504.
- Hardware: a busy rig → 409, a refused command or unsafe trajectory → 422.
- Bodies are ``{"detail": message, ...}`` with extra machine-readable keys (``current_state``,
  ``row``, ``column``, ``field``, ``held_by``).
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from core.errors import CoreError
from core.recognition import RecognitionFinishedError
from hardware import errors as hw

logger = logging.getLogger(__name__)


class AppError(Exception):
    """Base error of :mod:`app`: carries its HTTP status and extra fields for the body.

    Args:
        message: What was wrong, for a person.
        **extra: Machine-readable fields added to the response body (``None`` values dropped).
    """

    status_code = 400
    #: Headers of the response (``Retry-After`` of a 429, say).
    headers: dict[str, str] | None = None

    def __init__(self, message: str, **extra: Any) -> None:
        super().__init__(message)
        self.message = message
        self.extra = {key: value for key, value in extra.items() if value is not None}


class NotFoundError(AppError):
    """A resource id does not exist."""

    status_code = 404


class ConflictError(AppError):
    """The request is not allowed in the current state (give ``current_state``)."""

    status_code = 409


class BadInputError(AppError):
    """Well-formed request with unusable content (name ``field``, ``row`` or ``column``)."""

    status_code = 422


class PayloadTooLargeError(AppError):
    """A request body over the upload limit."""

    status_code = 413


class DeviceUnavailableError(AppError):
    """A device is not connected, disconnected or faulted."""

    status_code = 503


class DeviceTimeoutError(AppError):
    """A device did not answer in time."""

    status_code = 504


def _body(message: str, **extra: Any) -> dict[str, Any]:
    return {"detail": message, **{k: v for k, v in extra.items() if v is not None}}


def error_response(exc: Exception) -> JSONResponse:
    """The HTTP response for an error raised by app, core or hardware code."""
    if isinstance(exc, AppError):
        return JSONResponse(
            _body(exc.message, **exc.extra), status_code=exc.status_code, headers=exc.headers
        )
    if isinstance(exc, RecognitionFinishedError):
        return JSONResponse(_body(str(exc), current_state="completed"), status_code=409)
    if isinstance(exc, CoreError):
        row = getattr(exc, "row", None)
        column = getattr(exc, "column", None)
        return JSONResponse(_body(str(exc), row=row, column=column), status_code=422)
    mapped = map_hardware_error(exc)
    if mapped is not None:
        return error_response(mapped)
    logger.exception("unhandled error", exc_info=exc)
    return JSONResponse({"detail": "Internal server error."}, status_code=500)


def map_hardware_error(exc: Exception) -> AppError | None:
    """Translate a :class:`hardware.errors.HardwareError` into an app error (409/422/503/504)."""
    if not isinstance(exc, hw.HardwareError):
        return None
    name = type(exc).__name__
    if isinstance(exc, hw.DeviceTimeout):
        return DeviceTimeoutError(f"Device timeout: {exc}", device_error=name)
    if isinstance(exc, hw.RigBusy):
        return ConflictError(str(exc), held_by=exc.owner, device_error=name)
    if isinstance(exc, hw.LeaseError):
        return ConflictError(str(exc), device_error=name)
    if isinstance(exc, hw.ConfigurationError | hw.UnsafeTrajectoryError | hw.CommandRejected):
        return BadInputError(str(exc), device_error=name)
    return DeviceUnavailableError(f"Device unavailable: {exc}", device_error=name)


async def _handle(request: Request, exc: Exception) -> JSONResponse:
    return error_response(exc)


def install_error_handlers(app: FastAPI) -> None:
    """Register the handler for app, core and hardware errors (and a logged 500 for bugs)."""
    app.add_exception_handler(AppError, _handle)
    app.add_exception_handler(CoreError, _handle)
    app.add_exception_handler(hw.HardwareError, _handle)
