"""request_audit: every mutating API request (time, client, route, outcome, authentication)

Revision ID: 0004_request_audit
Revises: 0003_evaluations
Create Date: 2026-11-24 06:30:00.000000

"""
from typing import Sequence, Union

from alembic import op
import sqlalchemy as sa


# revision identifiers, used by Alembic.
revision: str = '0004_request_audit'
down_revision: Union[str, Sequence[str], None] = '0003_evaluations'
branch_labels: Union[str, Sequence[str], None] = None
depends_on: Union[str, Sequence[str], None] = None


def upgrade() -> None:
    """Upgrade schema."""
    op.create_table('request_audit',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('time', sa.DateTime(), nullable=False),
    sa.Column('client', sa.String(length=100), nullable=True),
    sa.Column('method', sa.String(length=10), nullable=False),
    sa.Column('path', sa.String(length=500), nullable=False),
    sa.Column('route', sa.String(length=200), nullable=True),
    sa.Column('status_code', sa.Integer(), nullable=False),
    sa.Column('authenticated', sa.Boolean(), nullable=False),
    sa.Column('auth_method', sa.String(length=20), nullable=True),
    sa.Column('duration_ms', sa.Float(), nullable=False),
    sa.PrimaryKeyConstraint('id')
    )
    with op.batch_alter_table('request_audit', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_request_audit_time'), ['time'], unique=False)


def downgrade() -> None:
    """Downgrade schema."""
    with op.batch_alter_table('request_audit', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_request_audit_time'))
    op.drop_table('request_audit')
