"""models.posterior: how each model's GP was conditioned

Structure (dense / kronecker / sparse) and, for a sparse model, its inducing touches: the
model document's ``posterior`` field. Rows from before stay NULL and are rebuilt with
``core.gp.posterior.condition``'s default structure, as they were.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-28 10:00:00.000000

"""

from typing import Sequence, Union

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "0002"
down_revision: Union[str, Sequence[str], None] = "0001"
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    """Upgrade schema."""
    with op.batch_alter_table("models", schema=None) as batch_op:
        batch_op.add_column(sa.Column("posterior", sa.JSON(), nullable=True))


def downgrade() -> None:
    """Downgrade schema."""
    with op.batch_alter_table("models", schema=None) as batch_op:
        batch_op.drop_column("posterior")
