"""datasets.touch_duration_s: how long every touch of a dataset lasted as planned

An action means a joint trajectory of one duration; the same action at another duration is
another touch. A collection records its touches' duration, as a training CSV's optional
``duration_s`` column and a raw-touch line's ``duration_s`` key do, and a model of the dataset
recognises with touches as long. Datasets from before recorded none: NULL (the rig's default
duration).

Revision ID: 0008_dataset_touch_duration
Revises: 0007_sample_time
Create Date: 2026-11-29 21:40:00.000000

"""
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa


# revision identifiers, used by Alembic.
revision: str = '0008_dataset_touch_duration'
down_revision: Union[str, Sequence[str], None] = '0007_sample_time'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


# ``datasets`` is the parent of ``samples`` (ON DELETE CASCADE): a batch "move and copy" would
# drop it, and with foreign keys on SQLite then deletes every sample. Plain ALTER TABLE ADD/DROP
# COLUMN (SQLite 3.35 or later) changes it in place.


def upgrade() -> None:
    """Upgrade schema."""
    with op.batch_alter_table('datasets', schema=None, recreate='never') as batch_op:
        batch_op.add_column(sa.Column('touch_duration_s', sa.Float(), nullable=True))


def downgrade() -> None:
    """Downgrade schema."""
    with op.batch_alter_table('datasets', schema=None, recreate='never') as batch_op:
        batch_op.drop_column('touch_duration_s')
