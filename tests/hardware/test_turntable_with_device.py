"""A real GRBL turntable (run with ``--turntable-port /dev/ttyACM0``; skipped otherwise).

The table turns: keep the space around it clear and the finger away from the objects.
"""

from __future__ import annotations

import pytest

from hardware.transport import SerialTransport
from hardware.turntable import GRBL_BAUDRATE, Turntable


def test_connect_status_and_two_slots(turntable_port: str) -> None:
    table = Turntable(SerialTransport(turntable_port, GRBL_BAUDRATE))
    try:
        info = table.connect()
        assert info.version.startswith("1.1")
        assert info.settings[100] == pytest.approx(table.config.steps_per_degree)
        assert table.status().state == "Idle"
        assert table.move_to_slot(1) == pytest.approx(table.slot_angle(1), abs=0.1)
        assert table.move_to_slot(0) == pytest.approx(table.slot_angle(0), abs=0.1)
    finally:
        table.close()
