"""GRBL 1.1 serial protocol: messages, code tables and a line-oriented link.

The protocol lives here, apart from the turntable logic (:mod:`hardware.turntable`) and from the
bytes on the wire (:mod:`hardware.transport`):

- Commands are lines ending in ``\\n`` only. GRBL treats ``\\r`` as a line end too and answers an
  empty line with ``ok``, so ``\\r\\n`` would produce two answers for one command.
- Every line gets exactly one answer: ``ok`` or ``error:N``. ``ALARM:N``, ``[MSG:...]``, status
  reports ``<...>`` and the start-up banner are pushed at any time.
- Real-time commands are single bytes, never followed by a line end: ``?`` status report,
  ``!`` feed hold, ``~`` cycle start / resume, ``0x18`` soft reset.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

from hardware.errors import (
    DeviceTimeout,
    GrblAlarm,
    GrblCommandError,
    ProtocolError,
)
from hardware.transport import Transport

STATUS_QUERY = b"?"
FEED_HOLD = b"!"
CYCLE_START = b"~"
SOFT_RESET = b"\x18"

GRBL_ERRORS: dict[int, tuple[str, str]] = {
    1: (
        "Expected command letter",
        "G-code words consist of a letter and a value. Letter was not found.",
    ),
    2: (
        "Bad number format",
        "Missing the expected G-code word value or numeric value format is not valid.",
    ),
    3: ("Invalid statement", "Grbl '$' system command was not recognized or supported."),
    4: ("Value < 0", "Negative value received for an expected positive value."),
    5: ("Setting disabled", "Homing cycle failure. Homing is not enabled via settings."),
    6: ("Value < 3 usec", "Minimum step pulse time must be greater than 3usec."),
    7: (
        "EEPROM read fail. Using defaults",
        "An EEPROM read failed. Auto-restoring affected EEPROM to default values.",
    ),
    8: (
        "Not idle",
        "Grbl '$' command cannot be used unless Grbl is IDLE. Ensures smooth operation during a "
        "job.",
    ),
    9: ("G-code lock", "G-code commands are locked out during alarm or jog state."),
    10: ("Homing not enabled", "Soft limits cannot be enabled without homing also enabled."),
    11: (
        "Line overflow",
        "Max characters per line exceeded. Received command line was not executed.",
    ),
    12: (
        "Step rate > 30kHz",
        "Grbl '$' setting value cause the step rate to exceed the maximum supported.",
    ),
    13: ("Check Door", "Safety door detected as opened and door state initiated."),
    14: (
        "Line length exceeded",
        "Build info or startup line exceeded EEPROM line length limit. Line not stored.",
    ),
    15: ("Travel exceeded", "Jog target exceeds machine travel. Jog command has been ignored."),
    16: ("Invalid jog command", "Jog command has no '=' or contains prohibited g-code."),
    17: ("Setting disabled", "Laser mode requires PWM output."),
    20: ("Unsupported command", "Unsupported or invalid g-code command found in block."),
    21: (
        "Modal group violation",
        "More than one g-code command from same modal group found in block.",
    ),
    22: ("Undefined feed rate", "Feed rate has not yet been set or is undefined."),
    23: ("Invalid gcode ID:23", "G-code command in block requires an integer value."),
    24: (
        "Invalid gcode ID:24",
        "More than one g-code command that requires axis words found in block.",
    ),
    25: ("Invalid gcode ID:25", "Repeated g-code word found in block."),
    26: (
        "Invalid gcode ID:26",
        "No axis words found in block for g-code command or current modal state which requires "
        "them.",
    ),
    27: ("Invalid gcode ID:27", "Line number value is invalid."),
    28: ("Invalid gcode ID:28", "G-code command is missing a required value word."),
    29: ("Invalid gcode ID:29", "G59.x work coordinate systems are not supported."),
    30: ("Invalid gcode ID:30", "G53 only allowed with G0 and G1 motion modes."),
    31: (
        "Invalid gcode ID:31",
        "Axis words found in block when no command or current modal state uses them.",
    ),
    32: ("Invalid gcode ID:32", "G2 and G3 arcs require at least one in-plane axis word."),
    33: ("Invalid gcode ID:33", "Motion command target is invalid."),
    34: ("Invalid gcode ID:34", "Arc radius value is invalid."),
    35: ("Invalid gcode ID:35", "G2 and G3 arcs require at least one in-plane offset word."),
    36: ("Invalid gcode ID:36", "Unused value words found in block."),
    37: (
        "Invalid gcode ID:37",
        "G43.1 dynamic tool length offset is not assigned to configured tool length axis.",
    ),
    38: ("Invalid gcode ID:38", "Tool number greater than max supported value."),
}
"""GRBL 1.1 error codes: code → (name, description), from GRBL's ``error_codes_en_US.csv``."""

GRBL_ALARMS: dict[int, tuple[str, str]] = {
    1: (
        "Hard limit",
        "Hard limit has been triggered. Machine position is likely lost due to sudden halt. "
        "Re-homing is highly recommended.",
    ),
    2: (
        "Soft limit",
        "Soft limit alarm. G-code motion target exceeds machine travel. Machine position "
        "retained. Alarm may be safely unlocked.",
    ),
    3: (
        "Abort during cycle",
        "Reset while in motion. Machine position is likely lost due to sudden halt. Re-homing is "
        "highly recommended.",
    ),
    4: (
        "Probe fail",
        "Probe fail. Probe is not in the expected initial state before starting probe cycle when "
        "G38.2 and G38.3 is not triggered and G38.4 and G38.5 is triggered.",
    ),
    5: (
        "Probe fail",
        "Probe fail. Probe did not contact the workpiece within the programmed travel for G38.2 "
        "and G38.4.",
    ),
    6: ("Homing fail", "Homing fail. The active homing cycle was reset."),
    7: ("Homing fail", "Homing fail. Safety door was opened during homing cycle."),
    8: (
        "Homing fail",
        "Homing fail. Pull off travel failed to clear limit switch. Try increasing pull-off "
        "setting or check wiring.",
    ),
    9: (
        "Homing fail",
        "Homing fail. Could not find limit switch within search distances. Try increasing max "
        "travel, decreasing pull-off distance, or check wiring.",
    ),
}
"""GRBL 1.1 alarm codes: code → (name, description), from GRBL's ``alarm_codes_en_US.csv``."""

_BANNER = re.compile(r"^Grbl (\d+\.\d+)(\w*) \['\$' for help\]$")
_STATUS = re.compile(r"^<([A-Za-z]+)(?::(\d+))?((?:\|[^|>]*)*)>$")
_SETTING = re.compile(r"^\$(\d+)=(-?\d+(?:\.\d*)?)$")


def grbl_error(code: int, command: str) -> GrblCommandError:
    """The exception for ``error:code`` answered to ``command``."""
    name, meaning = GRBL_ERRORS.get(code, ("Unknown error", "not in the GRBL 1.1 error table"))
    return GrblCommandError(code, name, meaning, command)


def grbl_alarm(code: int) -> GrblAlarm:
    """The exception for ``ALARM:code``."""
    name, meaning = GRBL_ALARMS.get(code, ("Unknown alarm", "not in the GRBL 1.1 alarm table"))
    return GrblAlarm(code, name, meaning)


@dataclass(frozen=True)
class GrblStatus:
    """A parsed real-time status report, e.g. ``<Idle|MPos:36.000,0.000,0.000|FS:0,0>``.

    Attributes:
        state: ``Idle``, ``Run``, ``Hold``, ``Jog``, ``Alarm``, ``Door``, ``Check``, ``Home``,
            ``Sleep``.
        substate: The number after ``Hold:`` / ``Door:`` if any.
        machine_position: MPos (or WPos when the report uses work positions), one per axis.
        fields: Every ``name:value`` field of the report, raw.
    """

    state: str
    substate: int | None
    machine_position: tuple[float, ...]
    fields: dict[str, str] = field(default_factory=dict)


def parse_status(line: str) -> GrblStatus:
    """Parse a status report line.

    Raises:
        ProtocolError: The line is not a GRBL 1.1 status report.
    """
    match = _STATUS.match(line)
    if match is None:
        raise ProtocolError(f"not a GRBL status report: {line!r}")
    state, substate, rest = match.group(1), match.group(2), match.group(3)
    fields: dict[str, str] = {}
    for part in rest.split("|")[1:]:
        name, _, value = part.partition(":")
        fields[name] = value
    raw_position = fields.get("MPos", fields.get("WPos"))
    if raw_position is None:
        raise ProtocolError(f"status report without a position: {line!r}")
    try:
        position = tuple(float(v) for v in raw_position.split(","))
    except ValueError as exc:
        raise ProtocolError(f"status report with a bad position: {line!r}") from exc
    return GrblStatus(state, int(substate) if substate else None, position, fields)


def parse_banner(line: str) -> str | None:
    """The version in a start-up banner (``"1.1h"``), or None if the line is not one."""
    match = _BANNER.match(line)
    return None if match is None else match.group(1) + match.group(2)


def parse_setting(line: str) -> tuple[int, float] | None:
    """``"$100=5.000"`` → ``(100, 5.0)``; None for any other line."""
    match = _SETTING.match(line)
    return None if match is None else (int(match.group(1)), float(match.group(2)))


def move_command(axis_position_deg: float) -> str:
    """``G90 G0 X<deg>``: rapid move to an absolute position, three decimals."""
    return f"G90 G0 X{axis_position_deg:.3f}"


@dataclass(frozen=True)
class GrblReply:
    """The answer to one command line.

    Attributes:
        command: The line sent.
        lines: Lines received before ``ok`` (settings, messages), in order.
    """

    command: str
    lines: tuple[str, ...]


class GrblLink:
    """Line-level GRBL link over a transport.

    Push messages are handled as they arrive: status reports are kept as :attr:`last_status`,
    a banner is noted in :attr:`banner_version` (GRBL was reset), ``[MSG:...]`` lines are kept in
    :attr:`messages`; ``ALARM:N`` raises :class:`GrblAlarm` from whichever call is reading.

    Args:
        transport: The open transport.
        on_line: Optional callback receiving every line read (for logs).
    """

    def __init__(self, transport: Transport, on_line: Callable[[str], None] | None = None) -> None:
        self.transport = transport
        self.on_line = on_line
        self._buffer = bytearray()
        self.last_status: GrblStatus | None = None
        self.banner_version: str | None = None
        self.messages: list[str] = []
        self.resets_seen = 0

    # -- writing ------------------------------------------------------------------------------

    def send_line(self, line: str) -> None:
        """Write one command line, terminated by ``\\n`` alone."""
        if "\n" in line or "\r" in line:
            raise ProtocolError(f"a GRBL command must be a single line, received {line!r}")
        self.transport.write(line.encode("ascii") + b"\n")

    def send_realtime(self, command: bytes) -> None:
        """Write a single real-time byte (``?``, ``!``, ``~``, ``0x18``)."""
        if command not in (STATUS_QUERY, FEED_HOLD, CYCLE_START, SOFT_RESET):
            raise ProtocolError(f"not a GRBL real-time command: {command!r}")
        self.transport.write(command)

    # -- reading ------------------------------------------------------------------------------

    def discard_input(self) -> None:
        """Drop buffered bytes on both sides."""
        self._buffer.clear()
        self.transport.reset_input_buffer()

    def read_line(self, timeout_s: float) -> str | None:
        """The next non-empty line (without its line end), or None after ``timeout_s``."""
        deadline = self.transport.now() + max(0.0, timeout_s)
        while True:
            newline = self._find_line_end()
            if newline >= 0:
                raw = bytes(self._buffer[:newline])
                del self._buffer[: newline + 1]
                text = raw.decode("ascii", errors="replace").strip()
                if not text:
                    continue
                if self.on_line is not None:
                    self.on_line(text)
                return text
            remaining = deadline - self.transport.now()
            if remaining <= 0:
                return None
            chunk = self.transport.read(4096, remaining)
            if not chunk:
                continue
            self._buffer.extend(chunk)

    def _find_line_end(self) -> int:
        for index, byte in enumerate(self._buffer):
            if byte in (0x0A, 0x0D):
                return index
        return -1

    def handle_push(self, line: str) -> bool:
        """Handle a push message; False if ``line`` is not one."""
        if line.startswith("<"):
            self.last_status = parse_status(line)
            return True
        if line.startswith("ALARM:"):
            raise grbl_alarm(_code(line, "ALARM:"))
        version = parse_banner(line)
        if version is not None:
            self.banner_version = version
            self.resets_seen += 1
            return True
        if line.startswith("[") and line.endswith("]"):
            self.messages.append(line)
            return True
        return False

    def next_message(self, timeout_s: float) -> str | None:
        """Read lines until one that is not a push message; handle push messages on the way.

        Returns:
            ``"ok"``, ``"error:N"``, a ``$N=value`` line, or any other non-push line; None on
            timeout.

        Raises:
            GrblAlarm: An ``ALARM:N`` line arrived.
        """
        deadline = self.transport.now() + max(0.0, timeout_s)
        while True:
            line = self.read_line(max(0.0, deadline - self.transport.now()))
            if line is None:
                return None
            if not self.handle_push(line):
                return line

    def request(self, line: str, timeout_s: float) -> GrblReply:
        """Send a command line and wait for its ``ok``.

        Raises:
            GrblCommandError: GRBL answered ``error:N``.
            GrblAlarm: An alarm arrived while waiting.
            DeviceTimeout: No answer within ``timeout_s``.
        """
        self.send_line(line)
        collected: list[str] = []
        while True:
            answer = self.next_message(timeout_s)
            if answer is None:
                raise DeviceTimeout(
                    f"{self.transport.name}: no answer from GRBL to {line!r} within "
                    f"{timeout_s:g} s."
                )
            if answer == "ok":
                return GrblReply(line, tuple(collected))
            if answer.startswith("error:"):
                raise grbl_error(_code(answer, "error:"), line)
            collected.append(answer)

    def query_status(self, timeout_s: float) -> GrblStatus | None:
        """Send ``?`` and wait for the status report; None on timeout.

        Raises:
            GrblAlarm: An alarm arrived while waiting.
            ProtocolError: An ``ok`` / ``error`` arrived, answering no command of ours.
        """
        self.last_status = None
        self.send_realtime(STATUS_QUERY)
        deadline = self.transport.now() + timeout_s
        while True:
            line = self.read_line(max(0.0, deadline - self.transport.now()))
            if line is None:
                return None
            if self.handle_push(line):
                if self.last_status is not None:
                    return self.last_status
                continue
            raise ProtocolError(
                f"{self.transport.name}: unexpected {line!r} while waiting for a status report."
            )


def _code(line: str, prefix: str) -> int:
    try:
        return int(line[len(prefix) :])
    except ValueError as exc:
        raise ProtocolError(f"malformed GRBL line {line!r}") from exc
