"""evaluation_trials.refused: a trial ended because the rig refused one of its touches

The trial's ``record`` is then a ``RefusedTrial`` document (the touch, its action and the
device's message). Rows from before are completed trials: false.

Revision ID: 0005_evaluation_trial_refused
Revises: 0004_request_audit
Create Date: 2026-11-24 12:45:00.000000

"""
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa


# revision identifiers, used by Alembic.
revision: str = '0005_evaluation_trial_refused'
down_revision: Union[str, Sequence[str], None] = '0004_request_audit'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    """Upgrade schema."""
    with op.batch_alter_table('evaluation_trials', schema=None) as batch_op:
        batch_op.add_column(
            sa.Column('refused', sa.Boolean(), server_default=sa.false(), nullable=False)
        )


def downgrade() -> None:
    """Downgrade schema."""
    with op.batch_alter_table('evaluation_trials', schema=None) as batch_op:
        batch_op.drop_column('refused')
