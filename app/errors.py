"""Errors of the app and the one place that maps every error to an HTTP answer.

- :class:`NotFoundError` → 404, :class:`ConflictError` → 409 (with the current state),
  :class:`BadInputError` and :class:`core.errors.CoreError` → 422 (naming field, row, column),
  a device unavailable → 503, a device timeout → 504.
- Hardware: a busy rig → 409, a refused command or unsafe trajectory → 422.
- A request FastAPI cannot validate → 422 listing the errors; a body it cannot parse as JSON
  (nested too deep, not UTF-8, an integer past Python's digit limit) → 400 saying why; routing
  errors (404, 405) as Starlette answers them.
- Anything else is a bug: logged, and answered 500 ``{"detail": "Internal server error."}``.
- Bodies are ``{"detail": message, ...}`` with extra machine-readable keys (``current_state``,
  ``row``, ``column``, ``field``, ``held_by``), made JSON-safe by :func:`json_safe` (a NaN or
  infinity the client sent is quoted as a string, long inputs are shortened).
"""

from __future__ import annotations

import logging
import math
import sys
from collections.abc import Mapping
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from fastapi.utils import is_body_allowed_for_status_code
from starlette.exceptions import HTTPException

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


#: Longest string, and most items of a list or object, an error body quotes (a request's
#: values quoted back are cut there; the app's own messages are shorter).
MAX_QUOTED_CHARACTERS = 1000
MAX_QUOTED_ITEMS = 100
#: Deepest nesting of a quoted value; deeper parts are replaced by "…".
MAX_QUOTED_DEPTH = 8


def json_safe(value: Any, depth: int = 0) -> Any:
    """``value`` as plain JSON any encoder writes: what a client sent, quoted in an error body.

    Non-finite floats become the strings ``"NaN"``, ``"Infinity"``, ``"-Infinity"`` (strict
    JSON has no such numbers); bytes are decoded as UTF-8 with replacement; strings lose lone
    surrogates (which UTF-8 cannot encode) and are shortened to :data:`MAX_QUOTED_CHARACTERS`;
    lists and objects keep their first :data:`MAX_QUOTED_ITEMS` items and
    :data:`MAX_QUOTED_DEPTH` levels; anything else is written with ``str``.
    """
    if value is None or isinstance(value, bool | int):
        return value
    if isinstance(value, float):
        if math.isfinite(value):
            return value
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, bytes | bytearray):
        return json_safe(bytes(value).decode("utf-8", errors="replace"), depth)
    if isinstance(value, str):
        text = value.encode("utf-8", errors="replace").decode("utf-8")
        if len(text) > MAX_QUOTED_CHARACTERS:
            return f"{text[:MAX_QUOTED_CHARACTERS]}… ({len(text)} characters)"
        return text
    if depth >= MAX_QUOTED_DEPTH:
        return "…"
    if isinstance(value, dict):
        items = list(value.items())
        quoted = {
            str(json_safe(str(key))): json_safe(item, depth + 1)
            for key, item in items[:MAX_QUOTED_ITEMS]
        }
        if len(items) > MAX_QUOTED_ITEMS:
            quoted["…"] = f"{len(items) - MAX_QUOTED_ITEMS} more fields"
        return quoted
    if isinstance(value, list | tuple):
        quoted_items = [json_safe(item, depth + 1) for item in value[:MAX_QUOTED_ITEMS]]
        if len(value) > MAX_QUOTED_ITEMS:
            quoted_items.append(f"… {len(value) - MAX_QUOTED_ITEMS} more items")
        return quoted_items
    return json_safe(str(value), depth)


def _response(
    status_code: int, message: Any, headers: Mapping[str, str] | None = None, **extra: Any
) -> JSONResponse:
    body = {"detail": message, **{k: v for k, v in extra.items() if v is not None}}
    return JSONResponse(json_safe(body), status_code=status_code, headers=headers)


def _unreadable_body(cause: BaseException) -> str:
    """Why FastAPI could not parse a request body as JSON (it answers only "There was an
    error parsing the body")."""
    if isinstance(cause, RecursionError):
        return "The request body is not JSON this server reads: it is nested too deeply."
    if isinstance(cause, UnicodeDecodeError):
        return f"The request body is not UTF-8 JSON ({cause.reason} at byte {cause.start})."
    if isinstance(cause, ValueError) and "digits" in str(cause):
        return (
            "The request body is not JSON this server reads: an integer has more than "
            f"{sys.get_int_max_str_digits()} digits."
        )
    return f"The request body is not JSON this server reads ({type(cause).__name__})."


def error_response(exc: Exception) -> Response:
    """The HTTP response for any error raised while serving a request (a logged 500 for one
    that is not a known kind: a bug)."""
    response = _known_error_response(exc)
    if response is None:
        logger.exception("unhandled error", exc_info=exc)
        return _response(500, "Internal server error.")
    return response


def _known_error_response(exc: Exception) -> Response | None:
    if isinstance(exc, AppError):
        return _response(exc.status_code, exc.message, exc.headers, **exc.extra)
    if isinstance(exc, RequestValidationError):
        return _response(422, exc.errors())
    if isinstance(exc, HTTPException):
        cause = exc.__cause__
        if isinstance(cause, Exception):
            # FastAPI answers anything that went wrong reading a body with a bare 400; answer
            # the cause instead (a body over the limit, a parse error).
            return _known_error_response(cause) or _response(400, _unreadable_body(cause))
        if not is_body_allowed_for_status_code(exc.status_code):
            return Response(status_code=exc.status_code, headers=exc.headers)
        return _response(exc.status_code, exc.detail, exc.headers)
    if isinstance(exc, RecognitionFinishedError):
        return _response(409, str(exc), current_state="completed")
    if isinstance(exc, CoreError):
        row = getattr(exc, "row", None)
        column = getattr(exc, "column", None)
        return _response(422, str(exc), row=row, column=column)
    mapped = map_hardware_error(exc)
    return None if mapped is None else _known_error_response(mapped)


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


async def _handle(request: Request, exc: Exception) -> Response:
    return error_response(exc)


def install_error_handlers(app: FastAPI) -> None:
    """Answer every error with :func:`error_response`: app, core and hardware errors, requests
    FastAPI refuses (validation, unreadable bodies, routing), and a logged 500 for bugs."""
    for error in (
        AppError,
        CoreError,
        hw.HardwareError,
        RequestValidationError,
        HTTPException,
        Exception,
    ):
        app.add_exception_handler(error, _handle)
