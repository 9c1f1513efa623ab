"""Serve a simulated rig on pseudo-terminals until interrupted.

    python -m hardware.sim.serve [--speed 1] [--seed 0]

prints the three ports; any program can then open them as if the real devices were plugged in
(``activetouch rig status --turntable-port ...``, ``pytest --turntable-port ...``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from hardware.clock import ScaledClock
from hardware.sim.rig import simulated_devices, start_emulators


def main(argv: list[str] | None = None) -> int:
    """Start the emulators, print their ports, wait for SIGINT/SIGTERM."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", type=float, default=1.0, help="simulated s per real s")
    parser.add_argument("--seed", type=int, default=0, help="seed of the simulated world")
    args = parser.parse_args(argv)
    devices = simulated_devices(clock=ScaledClock(args.speed), seed=args.seed)
    emulators = start_emulators(devices)
    for name, emulator in emulators.items():
        sys.stdout.write(f"{name}={emulator.port}\n")
    sys.stdout.flush()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    while not stop.wait(0.5):
        pass
    for emulator in emulators.values():
        emulator.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
