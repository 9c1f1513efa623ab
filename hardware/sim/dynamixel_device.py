"""A Dynamixel Protocol 2.0 bus of X-series servos, seen as bytes (it plays the servos).

This module parses instruction packets and produces status packets itself — it is the device,
not a driver. It implements what the finger driver uses and what a real XM430 answers:
PING, READ, WRITE, REBOOT, SYNC READ, SYNC WRITE; byte stuffing; CRC-16 (polynomial 0x8005);
the status error byte (alert bit 0x80 while a hardware error is latched; result fail,
instruction, CRC, data range, data limit and access errors); EEPROM areas writable only with
torque off; read-only addresses. Joint motion and currents come from the shared
:class:`~hardware.sim.world.Plant`.

Faults: a silent servo, late replies, a corrupt reply, a hardware error, unplugging the bus.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from hardware.errors import ServoHardwareErrorFlags
from hardware.sim.device import SimulatedDevice
from hardware.sim.world import Plant

HEADER = b"\xff\xff\xfd\x00"
BROADCAST = 0xFE
INSTRUCTION_PING = 0x01
INSTRUCTION_READ = 0x02
INSTRUCTION_WRITE = 0x03
INSTRUCTION_REBOOT = 0x08
INSTRUCTION_SYNC_READ = 0x82
INSTRUCTION_SYNC_WRITE = 0x83
INSTRUCTION_STATUS = 0x55

ERROR_RESULT_FAIL = 1
ERROR_INSTRUCTION = 2
ERROR_CRC = 3
ERROR_DATA_RANGE = 4
ERROR_DATA_LENGTH = 5
ERROR_DATA_LIMIT = 6
ERROR_ACCESS = 7
ALERT = 0x80

MODEL_XM430_W350 = 1020
FIRMWARE_VERSION = 46
DEG_PER_TICK = 360.0 / 4096.0
CENTRE_TICK = 2048
MA_PER_UNIT = 2.69
DEG_S_PER_UNIT = 0.229 * 6.0
EEPROM_END = 64
READ_ONLY = set(range(0, 7)) | {69, 70} | set(range(120, 148))
TABLE_SIZE = 148


def _crc_table() -> list[int]:
    table = []
    for index in range(256):
        crc = index << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def dynamixel_crc(data: bytes) -> int:
    """CRC-16/BUYPASS (polynomial 0x8005, initial 0), as Protocol 2.0 uses."""
    crc = 0
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(payload: bytes) -> bytes:
    """Insert 0xFD after every FF FF FD in instruction/parameters (byte stuffing)."""
    out = bytearray()
    for byte in payload:
        out.append(byte)
        if byte == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(payload: bytes) -> bytes:
    """Remove the stuffing byte after every FF FF FD."""
    out = bytearray()
    index = 0
    while index < len(payload):
        byte = payload[index]
        out.append(byte)
        if (
            byte == 0xFD
            and len(out) >= 3
            and out[-3] == 0xFF
            and out[-2] == 0xFF
            and index + 1 < len(payload)
            and payload[index + 1] == 0xFD
        ):
            index += 1
        index += 1
    return bytes(out)


def build_packet(servo_id: int, instruction: int, parameters: bytes) -> bytes:
    """A complete packet (header, ID, length, instruction, stuffed parameters, CRC)."""
    body = stuff(bytes([instruction]) + parameters)
    length = len(body) + 2
    packet = HEADER + bytes([servo_id, length & 0xFF, length >> 8]) + body
    crc = dynamixel_crc(packet)
    return packet + bytes([crc & 0xFF, crc >> 8])


@dataclass
class _Servo:
    servo_id: int
    joint: int
    table: bytearray = field(default_factory=lambda: bytearray(TABLE_SIZE))
    muted: bool = False
    reply_delay_s: float = 0.0
    corrupt_replies: int = 0

    def put(self, address: int, value: int, size: int) -> None:
        self.table[address : address + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(
            size, "little"
        )

    def get(self, address: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.table[address : address + size], "little", signed=signed)


class DynamixelBus(SimulatedDevice):
    """Servos on one Protocol 2.0 bus.

    Args:
        plant: The physical world the servos move in.
        joints_by_id: Servo ID → plant joint index (0: FFJ3, 1: FFJ4).
        model_number: Model reported by PING (1020: XM430-W350).
    """

    def __init__(
        self,
        plant: Plant,
        joints_by_id: Mapping[int, int] | None = None,
        model_number: int = MODEL_XM430_W350,
    ) -> None:
        super().__init__()
        self.plant = plant
        self.clock = plant.clock
        mapping = dict(joints_by_id or {1: 0, 2: 1})
        self.servos: dict[int, _Servo] = {}
        for servo_id, joint in mapping.items():
            servo = _Servo(servo_id, joint)
            defaults = {
                (0, 2): model_number,
                (6, 1): FIRMWARE_VERSION,
                (7, 1): servo_id,
                (8, 1): 3,
                (11, 1): 3,
                (31, 1): 80,
                (32, 2): 160,
                (34, 2): 95,
                (36, 2): 885,
                (38, 2): 1193,
                (44, 4): 200,
                (48, 4): 4095,
                (52, 4): 0,
                (63, 1): 0x34,
                (68, 1): 2,
                (84, 2): 800,
                (144, 2): 120,
                (146, 1): 35,
            }
            for (address, size), value in defaults.items():
                servo.put(address, value, size)
            self.servos[servo_id] = servo
        self._in = bytearray()
        self._replies: list[tuple[float, bytes]] = []  # (due at, packet)
        self.packets_received = 0
        self.crc_errors = 0

    # -- ByteDevice ---------------------------------------------------------------------------

    def attach(self) -> None:
        """Opening the port changes nothing on a Dynamixel bus."""

    def receive(self, data: bytes) -> None:
        """Instruction bytes from the host."""
        with self.lock:
            self._in.extend(data)
            self._parse()

    def transmit(self, max_bytes: int) -> bytes:
        """Status packets due by now."""
        with self.lock:
            now = self.clock.now()
            out = bytearray()
            while self._replies and self._replies[0][0] <= now and len(out) < max_bytes:
                _, packet = self._replies.pop(0)
                out.extend(packet)
            if len(out) > max_bytes:
                self._replies.insert(0, (now, bytes(out[max_bytes:])))
                del out[max_bytes:]
            return bytes(out)

    # -- fault injection ----------------------------------------------------------------------

    def mute(self, servo_id: int, muted: bool = True) -> None:
        """A servo stops answering (as if its ID were wrong or its power lost)."""
        with self.lock:
            self.servos[servo_id].muted = muted

    def delay_replies(self, servo_id: int, delay_s: float) -> None:
        """A servo answers ``delay_s`` late (longer than the host's timeout: a late reply)."""
        with self.lock:
            self.servos[servo_id].reply_delay_s = delay_s

    def corrupt_replies(self, servo_id: int, count: int = 1) -> None:
        """The next ``count`` replies of a servo have a wrong CRC."""
        with self.lock:
            self.servos[servo_id].corrupt_replies = count

    def inject_hardware_error(self, servo_id: int, flags: ServoHardwareErrorFlags) -> None:
        """A servo latches a hardware error and shuts its torque off."""
        with self.lock:
            servo = self.servos[servo_id]
            self.plant.inject_hardware_error(servo.joint, flags)
            servo.put(64, 0, 1)

    # -- packets ------------------------------------------------------------------------------

    def _parse(self) -> None:
        buffer = self._in
        while True:
            start = buffer.find(HEADER)
            if start < 0:
                del buffer[: max(0, len(buffer) - 3)]
                return
            del buffer[:start]
            if len(buffer) < 7:
                return
            length = buffer[5] | (buffer[6] << 8)
            total = 7 + length
            if length < 3 or total > 1024:
                del buffer[:1]
                continue
            if len(buffer) < total:
                return
            packet = bytes(buffer[:total])
            del buffer[:total]
            self.packets_received += 1
            servo_id = packet[4]
            crc = packet[-2] | (packet[-1] << 8)
            if dynamixel_crc(packet[:-2]) != crc:
                self.crc_errors += 1
                if servo_id in self.servos:
                    self._status(self.servos[servo_id], ERROR_CRC)
                continue
            payload = unstuff(packet[7:-2])
            self._dispatch(servo_id, payload[0], payload[1:])

    def _status(self, servo: _Servo, error: int, data: bytes = b"") -> None:
        if servo.muted:
            return
        flags = self.plant.hardware_error(servo.joint)
        if flags:
            error |= ALERT
        packet = bytearray(build_packet(servo.servo_id, INSTRUCTION_STATUS, bytes([error]) + data))
        if servo.corrupt_replies > 0:
            servo.corrupt_replies -= 1
            packet[-1] ^= 0xFF
        self._replies.append((self.clock.now() + servo.reply_delay_s, bytes(packet)))

    def _refresh(self, servo: _Servo) -> None:
        position, velocity, current, torque = self.plant.joint_state(servo.joint)
        servo.put(132, round(CENTRE_TICK + position / DEG_PER_TICK), 4)
        servo.put(128, round(velocity / DEG_S_PER_UNIT), 4)
        servo.put(126, round(current / MA_PER_UNIT), 2)
        servo.put(122, 1 if abs(velocity) > 0.5 else 0, 1)
        servo.put(70, int(self.plant.hardware_error(servo.joint)), 1)
        servo.put(64, 1 if torque else 0, 1)

    def _targets(self, servo_id: int) -> list[_Servo]:
        if servo_id == BROADCAST:
            return list(self.servos.values())
        servo = self.servos.get(servo_id)
        return [] if servo is None else [servo]

    def _dispatch(self, servo_id: int, instruction: int, params: bytes) -> None:
        if instruction == INSTRUCTION_SYNC_WRITE:
            self._sync_write(params)
            return
        if instruction == INSTRUCTION_SYNC_READ:
            self._sync_read(params)
            return
        for servo in self._targets(servo_id):
            reply = servo_id != BROADCAST or instruction == INSTRUCTION_PING
            if instruction == INSTRUCTION_PING:
                self._status(servo, 0, bytes(servo.table[0:2] + servo.table[6:7]))
            elif instruction == INSTRUCTION_READ:
                self._read(servo, params, reply)
            elif instruction == INSTRUCTION_WRITE:
                self._write(servo, params, reply)
            elif instruction == INSTRUCTION_REBOOT:
                if reply:
                    self._status(servo, 0)
                self.plant.reboot(servo.joint)
                servo.put(64, 0, 1)
            elif reply:
                self._status(servo, ERROR_INSTRUCTION)

    def _read(self, servo: _Servo, params: bytes, reply: bool) -> None:
        if len(params) != 4:
            if reply:
                self._status(servo, ERROR_DATA_LENGTH)
            return
        address = params[0] | (params[1] << 8)
        size = params[2] | (params[3] << 8)
        if address + size > TABLE_SIZE or size == 0:
            if reply:
                self._status(servo, ERROR_DATA_RANGE)
            return
        if address + size > 64:
            self._refresh(servo)
        if reply:
            self._status(servo, 0, bytes(servo.table[address : address + size]))

    def _write(self, servo: _Servo, params: bytes, reply: bool) -> None:
        if len(params) < 3:
            if reply:
                self._status(servo, ERROR_DATA_LENGTH)
            return
        address = params[0] | (params[1] << 8)
        data = params[2:]
        error = self._apply_write(servo, address, data)
        if reply:
            self._status(servo, error)

    def _apply_write(self, servo: _Servo, address: int, data: bytes) -> int:
        end = address + len(data)
        if end > TABLE_SIZE:
            return ERROR_DATA_RANGE
        if any(a in READ_ONLY for a in range(address, end)):
            return ERROR_ACCESS
        torque_on = self.plant.joint_state(servo.joint)[3]
        if address < EEPROM_END and torque_on:
            return ERROR_ACCESS
        value = int.from_bytes(data, "little", signed=False)
        if address == 64 and len(data) == 1:
            if value not in (0, 1):
                return ERROR_DATA_RANGE
            if value == 1 and self.plant.hardware_error(servo.joint):
                return ERROR_RESULT_FAIL
            servo.put(64, value, 1)
            self.plant.set_torque(servo.joint, value == 1)
            return 0
        if address == 116 and len(data) == 4:
            tick = int.from_bytes(data, "little", signed=True)
            if not servo.get(52, 4) <= tick <= servo.get(48, 4):
                return ERROR_DATA_LIMIT
            servo.put(116, tick, 4)
            if torque_on:
                self.plant.set_goal(servo.joint, (tick - CENTRE_TICK) * DEG_PER_TICK)
            return 0
        if address == 112 and len(data) == 4:
            servo.put(112, value, 4)
            self.plant.set_max_velocity(servo.joint, value * DEG_S_PER_UNIT)
            return 0
        if address == 11 and len(data) == 1 and value not in (0, 1, 3, 4, 5, 16):
            return ERROR_DATA_RANGE
        servo.table[address:end] = data
        return 0

    def _sync_write(self, params: bytes) -> None:
        if len(params) < 4:
            return
        address = params[0] | (params[1] << 8)
        size = params[2] | (params[3] << 8)
        block = params[4:]
        for offset in range(0, len(block) - size, size + 1):
            servo = self.servos.get(block[offset])
            if servo is not None:
                self._apply_write(servo, address, block[offset + 1 : offset + 1 + size])

    def _sync_read(self, params: bytes) -> None:
        if len(params) < 5:
            return
        address = params[0] | (params[1] << 8)
        size = params[2] | (params[3] << 8)
        for servo_id in params[4:]:
            servo = self.servos.get(servo_id)
            if servo is not None:
                self._read(
                    servo, bytes([address & 0xFF, address >> 8, size & 0xFF, size >> 8]), True
                )
