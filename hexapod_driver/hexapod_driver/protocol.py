"""Dynamixel Protocol 1.0 as spoken by the AX-12A: packets, checksum, control table. Pure Python.

Instruction packet (master -> servo)::

    0xFF 0xFF ID LENGTH INSTRUCTION PARAM_1 ... PARAM_N CHECKSUM      LENGTH = N + 2

Status packet (servo -> master)::

    0xFF 0xFF ID LENGTH ERROR PARAM_1 ... PARAM_N CHECKSUM            LENGTH = N + 2

``CHECKSUM = ~(ID + LENGTH + INSTRUCTION|ERROR + sum(PARAM)) & 0xFF``. Multi-byte values are
little endian. ID 254 is the broadcast ID: no servo answers a broadcast instruction.

The AX-12A has no SYNC_READ and does not implement BULK_READ; positions are read one servo at a
time, which is the paper's T_com. One :class:`PacketParser` frames the byte stream on both sides
of the line: the bus emulator's (the servos) and the driver's transport
(:mod:`hexapod_driver.bus.transport`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

# Status-packet error bits: defined once with the servo in hexapod_model, re-exported here (p.ERR_*)
from hexapod_model.servo import (  # noqa: F401
    ERR_ANGLE_LIMIT,
    ERR_CHECKSUM,
    ERR_INPUT_VOLTAGE,
    ERR_INSTRUCTION,
    ERR_OVERHEATING,
    ERR_OVERLOAD,
    ERR_RANGE,
    ERROR_BIT_NAMES,
    describe_error,
)

HEADER = b'\xff\xff'
BROADCAST_ID = 0xFE
MAX_ID = 253
AX12A_MODEL_NUMBER = 12

# Instructions
PING = 0x01
READ = 0x02
WRITE = 0x03
REG_WRITE = 0x04
ACTION = 0x05
RESET = 0x06
SYNC_WRITE = 0x83
BULK_READ = 0x92          # MX/AX-18 only: an AX-12A does not answer it
INSTRUCTION_NAMES = {PING: 'PING', READ: 'READ', WRITE: 'WRITE', REG_WRITE: 'REG_WRITE',
                     ACTION: 'ACTION', RESET: 'RESET', SYNC_WRITE: 'SYNC_WRITE', BULK_READ: 'BULK_READ'}

# Status return level (address 16)
RETURN_PING_ONLY = 0
RETURN_READ_ONLY = 1
RETURN_ALL = 2

# Bus timing constants of the UART (8N1: start + 8 data + stop)
BITS_PER_BYTE = 10
RETURN_DELAY_UNIT_S = 2e-6       # address 5 counts in units of 2 us
MOVING_SPEED_UNIT_RPM = 0.111    # address 32/38: about 0.111 rpm per unit
LOAD_DIRECTION_BIT = 0x400       # address 40: bit 10 = direction (1 = clockwise)
LOAD_MAGNITUDE_MASK = 0x3FF
VOLTAGE_UNIT_V = 0.1             # address 42 and voltage limits 12/13


class ProtocolError(ValueError):
    """A byte sequence is not a valid Protocol 1.0 packet; the message says what is wrong."""


def checksum(body: Iterable[int]) -> int:
    """Checksum of ID, LENGTH, INSTRUCTION/ERROR and parameters (everything but header and checksum)."""
    return (~sum(body)) & 0xFF


def _check_byte(value: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFF:
        raise ProtocolError(f'{what} must be a byte 0..255, got {value!r}')
    return value


def encode_instruction(servo_id: int, instruction: int, params: Iterable[int] = ()) -> bytes:
    """Build an instruction packet."""
    _check_byte(servo_id, 'servo id')
    _check_byte(instruction, 'instruction')
    p = [_check_byte(b, 'parameter') for b in params]
    if len(p) + 2 > 0xFF:
        raise ProtocolError(f'too many parameters ({len(p)}) for one packet')
    body = [servo_id, len(p) + 2, instruction, *p]
    return HEADER + bytes(body) + bytes([checksum(body)])


def encode_status(servo_id: int, error: int, params: Iterable[int] = ()) -> bytes:
    """Build a status packet (what a servo answers)."""
    _check_byte(error, 'error byte')
    return encode_instruction(servo_id, error, params)


@dataclass(frozen=True)
class Packet:
    """A decoded packet. ``code`` is the instruction (instruction packet) or error byte (status)."""

    servo_id: int
    code: int
    params: bytes
    checksum_ok: bool

    @property
    def length(self) -> int:
        return len(self.params) + 2


def decode_packet(raw: bytes) -> Packet:
    """Decode exactly one packet (header included); a bad checksum is reported, not raised."""
    raw = bytes(raw)
    if len(raw) < 6:
        raise ProtocolError(f'packet too short ({len(raw)} bytes; at least 6)')
    if raw[:2] != HEADER:
        raise ProtocolError(f'packet does not start with 0xFF 0xFF: {raw[:2].hex(" ")}')
    length = raw[3]
    if length < 2:
        raise ProtocolError(f'LENGTH byte {length} < 2')
    if len(raw) != length + 4:
        raise ProtocolError(f'LENGTH byte says {length + 4} bytes, got {len(raw)}')
    body = raw[2:-1]
    return Packet(servo_id=raw[2], code=raw[4], params=raw[5:-1], checksum_ok=checksum(body) == raw[-1])


class PacketParser:
    """Incremental parser of a byte stream into packets (resynchronises on garbage).

    Feed it whatever the line delivered; it yields complete packets, including those with a bad
    checksum (``checksum_ok`` False) so a servo can answer with ERR_CHECKSUM.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.discarded_bytes = 0

    def feed(self, data: bytes) -> Iterator[Packet]:
        self._buf.extend(data)
        while True:
            start = self._buf.find(HEADER)
            if start < 0:
                # keep a trailing 0xFF: it may be the first header byte
                keep = 1 if self._buf.endswith(b'\xff') else 0
                self.discarded_bytes += len(self._buf) - keep
                del self._buf[:len(self._buf) - keep]
                return
            if start:
                self.discarded_bytes += start
                del self._buf[:start]
            # 0xFF 0xFF 0xFF ...: the header is the last two 0xFF before a non-0xFF id
            while len(self._buf) > 2 and self._buf[2] == 0xFF:
                self.discarded_bytes += 1
                del self._buf[0]
            if len(self._buf) < 4:
                return
            length = self._buf[3]
            if length < 2:
                self.discarded_bytes += 2
                del self._buf[:2]
                continue
            total = length + 4
            if len(self._buf) < total:
                return
            raw = bytes(self._buf[:total])
            del self._buf[:total]
            yield decode_packet(raw)

    @property
    def pending(self) -> int:
        """Bytes received but not yet forming a complete packet."""
        return len(self._buf)

    def clear(self) -> int:
        """Forget the bytes not yet parsed (they answer nothing any more); returns how many."""
        n = len(self._buf)
        self._buf.clear()
        return n


# ----------------------------------------------------------------------------- control table
EEPROM = 'EEPROM'
RAM = 'RAM'


@dataclass(frozen=True)
class Register:
    """One control-table entry of the AX-12A."""

    name: str
    address: int
    size: int               # bytes (1 or 2, little endian)
    area: str               # EEPROM (persists over power cycles) or RAM (reset at power-up)
    writable: bool
    default: int | None     # factory / power-up value; None = set by the servo (present values)
    low: int = 0
    high: int = 0xFF


# AX-12A control table (e-manual, Protocol 1.0). Values are raw register units.
CONTROL_TABLE: tuple[Register, ...] = (
    Register('model_number', 0, 2, EEPROM, False, AX12A_MODEL_NUMBER, 0, 0xFFFF),
    Register('firmware_version', 2, 1, EEPROM, False, 24),
    Register('id', 3, 1, EEPROM, True, 1, 0, MAX_ID),
    Register('baud_rate', 4, 1, EEPROM, True, 1, 0, 254),           # 2 Mbps / (value + 1)
    Register('return_delay_time', 5, 1, EEPROM, True, 250, 0, 254),  # x 2 us
    Register('cw_angle_limit', 6, 2, EEPROM, True, 0, 0, 1023),
    Register('ccw_angle_limit', 8, 2, EEPROM, True, 1023, 0, 1023),
    Register('temperature_limit', 11, 1, EEPROM, True, 70, 10, 99),   # deg C
    Register('min_voltage_limit', 12, 1, EEPROM, True, 60, 50, 250),  # x 0.1 V
    Register('max_voltage_limit', 13, 1, EEPROM, True, 140, 50, 250),
    Register('max_torque', 14, 2, EEPROM, True, 1023, 0, 1023),
    Register('status_return_level', 16, 1, EEPROM, True, RETURN_ALL, 0, 2),
    Register('alarm_led', 17, 1, EEPROM, True, ERR_OVERHEATING | ERR_OVERLOAD, 0, 127),
    Register('alarm_shutdown', 18, 1, EEPROM, True, ERR_OVERHEATING | ERR_OVERLOAD, 0, 127),
    Register('torque_enable', 24, 1, RAM, True, 0, 0, 1),
    Register('led', 25, 1, RAM, True, 0, 0, 1),
    Register('cw_compliance_margin', 26, 1, RAM, True, 1, 0, 255),
    Register('ccw_compliance_margin', 27, 1, RAM, True, 1, 0, 255),
    Register('cw_compliance_slope', 28, 1, RAM, True, 32, 1, 254),
    Register('ccw_compliance_slope', 29, 1, RAM, True, 32, 1, 254),
    Register('goal_position', 30, 2, RAM, True, None, 0, 1023),
    Register('moving_speed', 32, 2, RAM, True, 0, 0, 2047),
    Register('torque_limit', 34, 2, RAM, True, None, 0, 1023),      # power-up value = max_torque
    Register('present_position', 36, 2, RAM, False, None, 0, 1023),
    Register('present_speed', 38, 2, RAM, False, None, 0, 2047),
    Register('present_load', 40, 2, RAM, False, None, 0, 2047),
    Register('present_voltage', 42, 1, RAM, False, None),
    Register('present_temperature', 43, 1, RAM, False, None),
    Register('registered', 44, 1, RAM, False, 0, 0, 1),
    Register('moving', 46, 1, RAM, False, 0, 0, 1),
    Register('lock', 47, 1, RAM, True, 0, 0, 1),
    Register('punch', 48, 2, RAM, True, 32, 0, 1023),
)
REGISTERS = {r.name: r for r in CONTROL_TABLE}
TABLE_SIZE = 50                       # addresses 0..49
EEPROM_END = 24                       # addresses below 24 are EEPROM
LOCK_WRITABLE = range(24, 36)         # with lock = 1 only addresses 24..35 may be written

# byte address -> (register, byte index within it)
BYTE_MAP: dict[int, tuple[Register, int]] = {}
for _r in CONTROL_TABLE:
    for _k in range(_r.size):
        BYTE_MAP[_r.address + _k] = (_r, _k)
del _r, _k


def register(name: str) -> Register:
    try:
        return REGISTERS[name]
    except KeyError:
        raise ProtocolError(f'no AX-12A register {name!r}; known: {sorted(REGISTERS)}') from None


def baud_of_register(value: int) -> float:
    """Baud rate [bit/s] selected by register 4."""
    return 2_000_000.0 / (value + 1)


def read_transaction_bytes(n_data: int) -> tuple[int, int]:
    """(instruction bytes, status bytes) of a READ of ``n_data`` bytes."""
    return 8, 6 + n_data


def read_bus_time_s(n_data: int, baud_rate: float, return_delay_s: float) -> float:
    """Theoretical wire time of one READ transaction: both packets at 10 bits/byte plus return delay."""
    tx, rx = read_transaction_bytes(n_data)
    return (tx + rx) * BITS_PER_BYTE / baud_rate + return_delay_s


def sync_write_bytes(n_servos: int, data_len: int) -> int:
    """Length of a SYNC_WRITE packet for ``n_servos`` servos with ``data_len`` bytes each."""
    return 8 + n_servos * (data_len + 1)


def word(v: int) -> list[int]:
    """A 16-bit register value as the two bytes a write carries (low first)."""
    return [int(v) & 0xFF, (int(v) >> 8) & 0xFF]


def u16(data: bytes) -> int:
    """The 16-bit register value of the first two bytes read (low first)."""
    return data[0] | data[1] << 8


def register_value(block: bytes, start: int, name: str) -> int:
    """The value of register ``name`` in ``block``, the bytes of one READ from address ``start``."""
    reg = register(name)
    raw = block[reg.address - start:reg.address - start + reg.size]
    if reg.address < start or len(raw) < reg.size:
        raise ProtocolError(f'register {name} ({reg.address}) is not in a read of {len(block)} bytes from {start}')
    return u16(raw) if reg.size == 2 else raw[0]


def decode_load(raw: int) -> float:
    """Register 40 -> signed fraction of maximum torque (positive = counter-clockwise)."""
    mag = (raw & LOAD_MAGNITUDE_MASK) / 1023.0
    return -mag if raw & LOAD_DIRECTION_BIT else mag


def encode_load(fraction: float) -> int:
    """Signed fraction of maximum torque -> register 40 (bit 10 = clockwise)."""
    mag = min(1023, int(round(abs(fraction) * 1023)))
    return mag | (LOAD_DIRECTION_BIT if fraction < 0 else 0)


def encode_speed(signed_units: float) -> int:
    """Signed speed in units of ~0.111 rpm -> register 38 (bit 10 = clockwise)."""
    mag = min(1023, int(round(abs(signed_units))))
    return mag | (LOAD_DIRECTION_BIT if signed_units < 0 else 0)
