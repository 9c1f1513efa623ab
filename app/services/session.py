"""Dashboard sign-in and sign-out: the token checked once, a server-side session issued."""

from __future__ import annotations

from app.config import Settings
from app.errors import ConflictError
from app.schemas import SessionStatus
from app.security.attempts import AttemptLimiter
from app.security.errors import TooManyAttemptsError, UnauthorizedError
from app.security.gate import Identity, token_matches
from app.security.sessions import Session, SessionStore


def sign_in(
    settings: Settings,
    sessions: SessionStore,
    presented: str | None,
    attempts: AttemptLimiter,
    client: str | None,
) -> Session:
    """Check ``presented`` against the token (constant time) and issue a session.

    A refused sign-in counts as a failure of ``client`` (its address); once it has too many
    within the window the token is not checked at all until the window has passed.

    Raises:
        UnauthorizedError: No token presented, or not the server's.
        TooManyAttemptsError: Too many wrong tokens from ``client`` lately.
        ConflictError: The server has no token (nothing to sign in to).
    """
    token = settings.token
    if token is None:
        raise ConflictError(
            "This server has no API token: no sign-in is needed.", current_state="open"
        )
    wait_s = attempts.retry_after_s(client)
    if wait_s is not None:
        raise TooManyAttemptsError(attempts.detail(wait_s), wait_s)
    if not presented or not token_matches(presented, token):
        attempts.record_failure(client)
        raise UnauthorizedError("Sign-in refused: that is not this server's API token.")
    return sessions.create()


def status(settings: Settings, identity: Identity, session: Session | None = None) -> SessionStatus:
    """How the caller is authenticated and what the server asks for."""
    return SessionStatus(
        authenticated=identity.authenticated,
        method=identity.method,
        auth_required=settings.token is not None,
        reads_need_auth=settings.reads_need_auth and settings.token is not None,
        expires_at=session.expires_at if session is not None else None,
    )


def sign_out(sessions: SessionStore, session_id: str | None) -> None:
    """End the session (if it exists)."""
    sessions.delete(session_id)
