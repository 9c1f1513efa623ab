"""A GRBL 1.1 dialect for one rotary axis, as bytes (a :class:`~hardware.transport.ByteDevice`).

It behaves like the real controller where the turntable driver depends on it:

- start-up and soft reset (``0x18``) print ``\\r\\nGrbl 1.1h ['$' for help]\\r\\n``; with homing
  enabled (``$22=1``) GRBL starts locked in Alarm and says ``[MSG:'$H'|'$X' to unlock]``;
  a reset during motion raises ``ALARM:3`` first;
- real-time bytes ``?`` ``!`` ``~`` ``0x18`` act at once, wherever they appear in the stream;
- lines end at ``\\n`` or ``\\r``; an empty line is answered ``ok`` (so ``\\r\\n`` gives two);
- ``$$``, ``$N=value``, ``$X``, ``$H``, ``G0``/``G1`` (X axis, ``G90``/``G91``), ``G4 P<s>``;
  ``G4`` is answered only once every queued motion has finished;
- errors and alarms with GRBL's codes (error:2, 3, 4, 5, 8, 9, 11, 20, 22, 28; ALARM:1, 3).

Motion follows a trapezoidal profile at ``$110`` (units/min) and ``$120`` (units/s²); positions are
quantised to ``1/$100``. Faults can be injected: an alarm during the next move, silence, garbage,
unplugging.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from hardware.clock import Clock
from hardware.sim.device import SimulatedDevice

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"
UNLOCK_HINT = b"[MSG:'$H'|'$X' to unlock]\r\n"
LINE_LIMIT = 80

DEFAULT_SETTINGS: dict[int, float] = {
    0: 10,
    1: 25,
    2: 0,
    3: 0,
    4: 0,
    5: 0,
    6: 0,
    10: 1,
    11: 0.010,
    12: 0.002,
    13: 0,
    20: 0,
    21: 0,
    22: 1,
    23: 0,
    24: 25.0,
    25: 1800.0,
    26: 250,
    27: 1.0,
    30: 1000,
    31: 0,
    32: 0,
    100: 250.0,
    101: 250.0,
    102: 250.0,
    110: 3600.0,
    111: 500.0,
    112: 500.0,
    120: 180.0,
    121: 10.0,
    122: 10.0,
    130: 360.0,
    131: 200.0,
    132: 200.0,
}
"""GRBL 1.1 factory settings, except a turntable's X rate, acceleration and homing seek rate
(60°/s, 180°/s², 30°/s).
``$100`` keeps the factory 250 so that a driver must set it."""

_INTEGER_SETTINGS = {0, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32}
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class _Segment:
    """One planned move of the X axis."""

    start_s: float
    start_deg: float
    end_deg: float
    duration_s: float
    accel_time_s: float
    peak_deg_s: float
    accel_deg_s2: float

    def position(self, moment: float) -> tuple[float, float]:
        """Position and velocity at ``moment`` (clamped to the segment)."""
        t = min(max(moment - self.start_s, 0.0), self.duration_s)
        direction = 1.0 if self.end_deg >= self.start_deg else -1.0
        accel, peak, ramp = self.accel_deg_s2, self.peak_deg_s, self.accel_time_s
        if t < ramp:
            return self.start_deg + direction * 0.5 * accel * t * t, direction * accel * t
        cruise = self.duration_s - 2.0 * ramp
        if t < ramp + cruise:
            distance = 0.5 * accel * ramp * ramp + peak * (t - ramp)
            return self.start_deg + direction * distance, direction * peak
        left = self.duration_s - t
        return self.end_deg - direction * 0.5 * accel * left * left, direction * accel * left

    @property
    def end_s(self) -> float:
        """When the move ends."""
        return self.start_s + self.duration_s


def _plan(start_s: float, start_deg: float, end_deg: float, rate: float, accel: float) -> _Segment:
    distance = abs(end_deg - start_deg)
    if distance == 0.0:
        return _Segment(start_s, start_deg, end_deg, 0.0, 0.0, 0.0, accel)
    if distance * accel <= rate * rate:  # triangular: never reaches the rate
        ramp = math.sqrt(distance / accel)
        return _Segment(start_s, start_deg, end_deg, 2.0 * ramp, ramp, accel * ramp, accel)
    ramp = rate / accel
    cruise = (distance - rate * ramp) / rate
    return _Segment(start_s, start_deg, end_deg, 2.0 * ramp + cruise, ramp, rate, accel)


class GrblDevice(SimulatedDevice):
    """The simulated controller.

    Args:
        clock: The simulation clock.
        settings: Overrides of :data:`DEFAULT_SETTINGS`.
    """

    def __init__(self, clock: Clock, settings: dict[int, float] | None = None) -> None:
        super().__init__()
        self.clock = clock
        self.settings = dict(DEFAULT_SETTINGS)
        self.settings.update(settings or {})
        self._line = bytearray()
        now = clock.now()
        self._history: list[_Segment] = [_Segment(now, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)]
        self._planned: list[_Segment] = []
        self._motion_end_s = now
        self._absolute = True
        self._state = "Idle"
        self._resume_target: float | None = None
        self._dwell: tuple[float, float] | None = None  # (queued at, seconds)
        self._pending_lines: list[str] = []
        self._homing = False
        self._muted = False
        self._alarm_next_move: tuple[int, float] | None = None
        self._alarm_due: tuple[float, int] | None = None
        self.received = bytearray()
        self.lines_received: list[str] = []
        self._boot()

    # -- ByteDevice ---------------------------------------------------------------------------

    def attach(self) -> None:
        """Opening the port resets the Arduino: GRBL boots and prints its banner."""
        with self.lock:
            self._update()
            self._reset(power_cycle=True)

    def receive(self, data: bytes) -> None:
        """Bytes from the host."""
        with self.lock:
            self._update()
            self.received.extend(data)
            for byte in data:
                self._byte(byte)

    def transmit(self, max_bytes: int) -> bytes:
        """Bytes GRBL has sent by now."""
        with self.lock:
            self._update()
            return b"" if self._muted else self._take(max_bytes)

    # -- fault injection ----------------------------------------------------------------------

    def mute(self, muted: bool = True) -> None:
        """Stop (or resume) sending anything; input is still processed."""
        with self.lock:
            self._muted = muted
            if muted:
                self._out.clear()

    def inject_output(self, data: bytes) -> None:
        """Push raw bytes to the host (garbage on the line)."""
        with self.lock:
            self._out.extend(data)

    def alarm_during_next_move(self, code: int = 1, fraction: float = 0.5) -> None:
        """The next move trips ``ALARM:code`` (1: a hard limit) ``fraction`` of the way."""
        with self.lock:
            self._alarm_next_move = (code, fraction)

    # -- the axis -----------------------------------------------------------------------------

    def position(self, moment: float | None = None) -> tuple[float, float]:
        """Machine position (deg) and velocity (deg/s) at ``moment`` (default now)."""
        with self.lock:
            when = self.clock.now() if moment is None else moment
            for segment in reversed(self._history):
                if segment.start_s <= when:
                    return segment.position(when)
            return self._history[0].position(when)

    @property
    def state(self) -> str:
        """GRBL's state name."""
        with self.lock:
            self._update()
            return self._state

    def _quantise(self, value: float) -> float:
        steps = self.settings.get(100, 250.0) or 1.0
        return round(value * steps) / steps

    def _freeze(self, moment: float) -> float:
        """Stop the axis dead at ``moment`` and flush the planner; returns the position."""
        position = self.position(moment)[0]
        self._history = [s for s in self._history if s.start_s <= moment][-50:]
        self._history.append(_Segment(moment, position, position, 0.0, 0.0, 0.0, 1.0))
        self._planned.clear()
        self._motion_end_s = moment
        return position

    def _queue_move(self, target_deg: float, rate_per_min: float | None = None) -> None:
        now = self.clock.now()
        start_s = max(now, self._motion_end_s)
        start_deg = self.position(start_s)[0]
        rate = (rate_per_min or self.settings[110]) / 60.0
        segment = _plan(start_s, start_deg, self._quantise(target_deg), rate, self.settings[120])
        self._planned.append(segment)
        self._history.append(segment)
        self._motion_end_s = segment.end_s
        if self._alarm_next_move is not None and segment.duration_s > 0:
            code, fraction = self._alarm_next_move
            self._alarm_next_move = None
            self._alarm_due = (segment.start_s + fraction * segment.duration_s, code)
        if self._state == "Idle":
            self._state = "Run"

    # -- time ---------------------------------------------------------------------------------

    def _update(self) -> None:
        now = self.clock.now()
        if self._alarm_due is not None and now >= self._alarm_due[0]:
            moment, code = self._alarm_due
            self._alarm_due = None
            self._freeze(moment)
            self._dwell = None
            self._pending_lines.clear()
            self._homing = False
            self._state = "Alarm"
            self._out.extend(f"ALARM:{code}\r\n".encode())
        if self._state in ("Run", "Home") and now >= self._motion_end_s:
            self._planned.clear()
            if self._homing:
                self._homing = False
                self._out.extend(b"ok\r\n")
            self._state = "Idle"
        while self._dwell is not None and self._state == "Idle":
            queued_at, seconds = self._dwell
            if now < max(queued_at, self._motion_end_s) + seconds:
                break
            self._dwell = None
            self._out.extend(b"ok\r\n")
            while self._pending_lines and self._dwell is None and self._state != "Alarm":
                self._execute(self._pending_lines.pop(0))

    # -- input --------------------------------------------------------------------------------

    def _byte(self, byte: int) -> None:
        if byte == 0x18:
            self._reset(power_cycle=False)
            return
        if byte == ord("?"):
            self._status_report()
            return
        if byte == ord("!"):
            self._feed_hold()
            return
        if byte == ord("~"):
            self._cycle_start()
            return
        if byte in (0x0A, 0x0D):
            line = self._line.decode("ascii", errors="replace")
            self._line.clear()
            if self._dwell is not None:
                self._pending_lines.append(line)  # GRBL reads no line during a dwell
            else:
                self._execute(line)
            return
        if len(self._line) <= LINE_LIMIT:
            self._line.append(byte)

    def _reply(self, text: str) -> None:
        self._out.extend(text.encode("ascii") + b"\r\n")

    def _boot(self) -> None:
        self._out.extend(BANNER)
        if self.settings.get(22, 0) == 1:
            self._state = "Alarm"
            self._out.extend(UNLOCK_HINT)
        else:
            self._state = "Idle"

    def _reset(self, power_cycle: bool) -> None:
        now = self.clock.now()
        moving = self._state in ("Run", "Hold", "Home") and not power_cycle
        self._freeze(now)
        self._dwell = None
        self._pending_lines.clear()
        self._homing = False
        self._alarm_due = None
        self._resume_target = None
        self._line.clear()
        if power_cycle:
            self._out.clear()
        if moving:
            self._out.extend(b"ALARM:3\r\n")
        self._boot()
        if moving and self._state != "Alarm":
            self._state = "Alarm"
            self._out.extend(UNLOCK_HINT)

    def _status_report(self) -> None:
        self._update()
        position, velocity = self.position()
        state = "Hold:0" if self._state == "Hold" else self._state
        feed = round(abs(velocity) * 60.0)
        self._reply(f"<{state}|MPos:{position:.3f},0.000,0.000|FS:{feed},0>")

    def _feed_hold(self) -> None:
        if self._state != "Run":
            return
        target = self._planned[-1].end_deg if self._planned else None
        self._freeze(self.clock.now())  # a simplification: the table stops at once
        self._resume_target = target
        self._state = "Hold"

    def _cycle_start(self) -> None:
        if self._state != "Hold":
            return
        self._state = "Idle"
        if self._resume_target is not None:
            self._queue_move(self._resume_target)
        self._resume_target = None

    def _execute(self, raw: str) -> None:
        self.lines_received.append(raw)
        line = raw.replace(" ", "").upper()
        if "(" in line:
            line = line.split("(")[0]
        line = line.split(";")[0]
        if len(raw) > LINE_LIMIT:
            self._reply("error:11")
            return
        if not line:
            self._reply("ok")
            return
        if line.startswith("$"):
            self._system_command(line)
            return
        self._gcode(line)

    def _system_command(self, line: str) -> None:
        busy = self._state in ("Run", "Hold", "Home")
        if line == "$$":
            for key in sorted(self.settings):
                value = self.settings[key]
                text = str(int(value)) if key in _INTEGER_SETTINGS else f"{value:.3f}"
                self._reply(f"${key}={text}")
            self._reply("ok")
            return
        if line == "$X":
            if busy:
                self._reply("error:8")
                return
            if self._state == "Alarm":
                self._reply("[MSG:Caution: Unlocked]")
                self._state = "Idle"
            self._reply("ok")
            return
        if line == "$H":
            if self.settings.get(22, 0) != 1:
                self._reply("error:5")
                return
            if busy:
                self._reply("error:8")
                return
            self._state = "Idle"
            self._queue_move(0.0, rate_per_min=self.settings[25])
            self._state = "Home"
            self._homing = True
            return
        match = re.fullmatch(r"\$(\d+)=(.*)", line)
        if match is None:
            self._reply("error:3")
            return
        if busy:
            self._reply("error:8")
            return
        key = int(match.group(1))
        if key not in self.settings:
            self._reply("error:3")
            return
        try:
            value = float(match.group(2))
        except ValueError:
            self._reply("error:2")
            return
        if value < 0:
            self._reply("error:4")
            return
        self.settings[key] = value
        self._reply("ok")

    def _gcode(self, line: str) -> None:
        if not line[0].isalpha():
            self._reply("error:1")
            return
        words = _WORD.findall(line)
        if "".join(letter + number for letter, number in words) != line:
            self._reply("error:2")
            return
        if self._state == "Alarm":
            self._reply("error:9")
            return
        motion: str | None = None
        dwell: float | None = None
        target: float | None = None
        feed: float | None = None
        is_dwell = False
        absolute = self._absolute
        for letter, number in words:
            value = float(number)
            if letter == "G":
                code = number.lstrip("0") or "0"
                if code in ("0", "1"):
                    motion = code
                elif code == "4":
                    is_dwell = True
                elif code in ("90", "91"):
                    absolute = code == "90"
                elif code in ("17", "20", "21", "94"):
                    pass
                else:
                    self._reply("error:20")
                    return
            elif letter == "X":
                target = value
            elif letter in ("Y", "Z"):
                pass
            elif letter == "P":
                dwell = value
            elif letter == "F":
                feed = value
            else:
                self._reply("error:20")
                return
        if is_dwell:
            if dwell is None:
                self._reply("error:28")
                return
            self._dwell = (self.clock.now(), dwell)
            self._update()
            return
        if motion == "1" and feed is None:
            self._reply("error:22")
            return
        self._absolute = absolute
        if target is not None:
            base = self.position(max(self.clock.now(), self._motion_end_s))[0]
            self._queue_move(target if absolute else base + target)
        self._reply("ok")
