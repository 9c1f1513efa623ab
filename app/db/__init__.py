"""The database: its tables (:mod:`app.db.tables`) and the engine, sessions and migrations of one
app (:mod:`app.db.session`). Only queries (:mod:`app.crud`) and services use it; routes never do.
"""

from app.db.session import Database, make_engine, upgrade_to_head

__all__ = ["Database", "make_engine", "upgrade_to_head"]
