"""One emulated AX-12A: its control table (EEPROM/RAM semantics, range, angle-limit and lock checks)
and its persistent error conditions (voltage, temperature, overload)."""
from __future__ import annotations

from hexapod_driver import protocol as p


class EmulatorError(RuntimeError):
    """The emulator cannot do what was asked (bad servo id, pty failure, ...)."""


class EmulatedServo:
    """One AX-12A: its control table and persistent error conditions."""

    def __init__(self, slot: int, servo_id: int, *, model_number: int = p.AX12A_MODEL_NUMBER,
                 temperature_limit_c: int = 70, supply_voltage_v: float = 12.0, ambient_c: float = 30.0):
        self.slot = slot
        self.mem = bytearray(p.TABLE_SIZE)
        for r in p.CONTROL_TABLE:
            if r.area == p.EEPROM and r.default is not None:
                self._put(r, r.default)
        self._put(p.REGISTERS['model_number'], model_number)
        self._put(p.REGISTERS['id'], servo_id)
        self._put(p.REGISTERS['temperature_limit'], temperature_limit_c)
        self.factory_eeprom = bytes(self.mem[:p.EEPROM_END])
        self.temperature_c = ambient_c
        self.voltage_v = supply_voltage_v
        self.overload = False
        self.pending: tuple[int, bytes] | None = None     # REG_WRITE (address, data)
        self.power_up(present_tick=512)

    # raw access
    def _put(self, reg: p.Register, value: int) -> None:
        self.mem[reg.address:reg.address + reg.size] = int(value).to_bytes(reg.size, 'little')

    def get(self, name: str) -> int:
        r = p.register(name)
        return int.from_bytes(self.mem[r.address:r.address + r.size], 'little')

    @property
    def servo_id(self) -> int:
        return self.mem[3]

    def set_register(self, name: str, value: int) -> None:
        """Set a register directly, as if configured earlier (test set-up; no checks, no side effects)."""
        self._put(p.register(name), value)

    def power_up(self, present_tick: int) -> None:
        """RAM to power-up values (EEPROM untouched); goal = present position."""
        for r in p.CONTROL_TABLE:
            if r.area == p.RAM and r.default is not None:
                self._put(r, r.default)
        self._put(p.REGISTERS['torque_limit'], self.get('max_torque'))
        self._put(p.REGISTERS['goal_position'], present_tick)
        self._put(p.REGISTERS['present_position'], present_tick)
        self.pending = None

    @property
    def torque_on(self) -> bool:
        return bool(self.mem[24]) and self.get('torque_limit') > 0

    def persistent_errors(self) -> int:
        bits = 0
        v10 = round(self.voltage_v / p.VOLTAGE_UNIT_V)
        if not self.get('min_voltage_limit') <= v10 <= self.get('max_voltage_limit'):
            bits |= p.ERR_INPUT_VOLTAGE
        if self.temperature_c > self.get('temperature_limit'):
            bits |= p.ERR_OVERHEATING
        if self.overload:
            bits |= p.ERR_OVERLOAD
        return bits

    def validate_write(self, address: int, data: bytes) -> tuple[int, dict[str, int]]:
        """(error bits, {register: new value}) of writing ``data`` at ``address``; nothing applied."""
        if not data or address + len(data) > p.TABLE_SIZE:
            return p.ERR_RANGE, {}
        locked = bool(self.mem[47])
        new = bytearray(self.mem)
        touched: dict[str, p.Register] = {}
        for k, b in enumerate(data):
            a = address + k
            entry = p.BYTE_MAP.get(a)
            if entry is None or not entry[0].writable or (locked and a not in p.LOCK_WRITABLE):
                return p.ERR_RANGE, {}
            new[a] = b
            touched[entry[0].name] = entry[0]
        values = {}
        for name, r in touched.items():
            v = int.from_bytes(new[r.address:r.address + r.size], 'little')
            if not r.low <= v <= r.high:
                return p.ERR_RANGE, {}
            values[name] = v
        if 'goal_position' in values:
            cw = values.get('cw_angle_limit', self.get('cw_angle_limit'))
            ccw = values.get('ccw_angle_limit', self.get('ccw_angle_limit'))
            if not (cw == 0 and ccw == 0) and not cw <= values['goal_position'] <= ccw:
                return p.ERR_ANGLE_LIMIT, {}
        return 0, values
