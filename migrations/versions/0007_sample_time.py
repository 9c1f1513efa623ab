"""samples.time_s: when each touch was made

A collection records each touch's time in seconds since its first touch; a training CSV's optional
``time_s`` column and a raw-touch line's ``time_s`` key say the same. The fit estimates from them
the slow drift of the sensor and the room that touches made close together share. Rows from
before recorded none: NULL.

Revision ID: 0007_sample_time
Revises: 0006_sample_placement
Create Date: 2026-11-27 03:55:38.000000

"""
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa


# revision identifiers, used by Alembic.
revision: str = '0007_sample_time'
down_revision: Union[str, Sequence[str], None] = '0006_sample_placement'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    """Upgrade schema."""
    with op.batch_alter_table('samples', schema=None) as batch_op:
        batch_op.add_column(sa.Column('time_s', sa.Float(), nullable=True))


def downgrade() -> None:
    """Downgrade schema."""
    with op.batch_alter_table('samples', schema=None) as batch_op:
        batch_op.drop_column('time_s')
