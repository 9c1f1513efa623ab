"""Errors of authentication and of the limit on wrong tokens (mapped to HTTP by
:func:`app.errors.error_response`)."""

from __future__ import annotations

from app.errors import AppError
from app.security.attempts import retry_after_header


class UnauthorizedError(AppError):
    """A request without the right token or session (401)."""

    status_code = 401


class ForbiddenError(AppError):
    """An authenticated request refused anyway (cross-origin or without the CSRF header; 403)."""

    status_code = 403


class TooManyAttemptsError(AppError):
    """Too many wrong tokens from one client address (429, with ``Retry-After``).

    Args:
        message: What happened and when to try again.
        retry_after_s: Seconds until the address may try again.
    """

    status_code = 429

    def __init__(self, message: str, retry_after_s: float) -> None:
        wait = retry_after_header(retry_after_s)
        super().__init__(message, retry_after_s=int(wait))
        self.headers = {"Retry-After": wait}
