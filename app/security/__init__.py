"""Who may read and change what: the token, dashboard sessions, the gate, the request audit.

- "Off loopback" is decided by the bind address (:attr:`app.config.Settings.reads_need_auth`):
  a server bound to a non-loopback address needs the token (``Authorization: Bearer``) or a
  signed-in dashboard session for every ``/api/v1`` request and for the 3D view at ``/viser/``,
  except ``GET /api/v1/health`` (which then only says that auth is required) and the sign-in
  itself. The client's address is not used: behind a reverse proxy or an SSH tunnel on the same
  machine every client would look like loopback.
- On loopback nothing changes: reads are open; with a token configured, changes need it.
- :mod:`app.security.sessions`: server-side sessions (random ids, expiry) behind an HttpOnly,
  SameSite=Strict cookie, so the browser's ``EventSource`` needs no token in its URL.
- :mod:`app.security.gate`: the ASGI middleware that enforces the above (constant-time token
  comparison, CSRF check on cookie-authenticated changes).
- :mod:`app.security.attempts`: wrong tokens (sign-in or bearer) limited per client address;
  beyond the limit, 429 with ``Retry-After``.
- :mod:`app.security.openapi`: the schemes above declared in the OpenAPI schema.
- :mod:`app.security.audit`: every mutating request recorded in the database, off the request
  path (a queue and a writer thread), so recording never delays or breaks it.
"""
