"""A real Dynamixel finger (run with ``--finger-port /dev/ttyUSB0``; skipped otherwise).

The finger moves by a few degrees around its zero pose: nothing may be within its reach.
"""

from __future__ import annotations

import time

import numpy as np

from hardware.finger import DYNAMIXEL_BAUDRATE, Finger
from hardware.transport import SerialTransport


def test_connect_and_small_moves(finger_port: str) -> None:
    finger = Finger(SerialTransport(finger_port, DYNAMIXEL_BAUDRATE))
    try:
        models = finger.connect()
        assert set(models) == {"FFJ3", "FFJ4"}
        for goal in ([3.0, 0.0], [0.0, 3.0], [0.0, 0.0]):
            finger.write_goal(goal)
            time.sleep(1.0)
            state = finger.read_state()
            np.testing.assert_allclose(state.positions_deg, goal, atol=1.0)
    finally:
        finger.set_torque(False)
        finger.close()
