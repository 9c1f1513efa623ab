"""samples.placement: which placement of its object each touch met

A collection places each object anew once every few touches and touches it several times in a
row at each placement; a training CSV's optional ``placement`` column and a raw-touch line's
``placement`` key say the same. The fit estimates from these groups how much one placement shifts
its touches alike (the model's ``placement_effect``). Rows from before recorded none: NULL.

Revision ID: 0006_sample_placement
Revises: 0005_evaluation_trial_refused
Create Date: 2026-11-26 09:40:00.000000

"""
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa


# revision identifiers, used by Alembic.
revision: str = '0006_sample_placement'
down_revision: Union[str, Sequence[str], None] = '0005_evaluation_trial_refused'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    """Upgrade schema."""
    with op.batch_alter_table('samples', schema=None) as batch_op:
        batch_op.add_column(sa.Column('placement', sa.Integer(), nullable=True))


def downgrade() -> None:
    """Downgrade schema."""
    with op.batch_alter_table('samples', schema=None) as batch_op:
        batch_op.drop_column('placement')
