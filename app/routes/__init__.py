"""Routes: one thin module per resource; the work is in :mod:`app.services`."""
