"""Errors of authentication (mapped to HTTP by :func:`app.errors.error_response`)."""

from __future__ import annotations

from app.errors import AppError


class UnauthorizedError(AppError):
    """A request without the right token or session (401)."""

    status_code = 401


class ForbiddenError(AppError):
    """An authenticated request refused anyway (cross-origin or without the CSRF header; 403)."""

    status_code = 403
