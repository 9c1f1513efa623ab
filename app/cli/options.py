"""Options that more than one ``activetouch`` command takes, written once."""

from __future__ import annotations

from typing import Annotated

import typer

PlacementOption = Annotated[
    str,
    typer.Option(
        help="Rig trials: place the object once per trial (trial) or anew before every touch "
        "(touch), as a collection does.",
    ),
]
"""``--placement``: see :class:`app.evaluation.spec.EvaluationSpec` (``trial`` by default)."""
