"""An AX-12A bus on a pseudo-terminal: 18 emulated servos speaking Protocol 1.0 byte for byte.

The driver (or any Dynamixel tool) opens the pty's slave path exactly as it would open
``/dev/ttyUSB0`` and cannot tell the difference: instruction packets are parsed with checksum
checks, status packets carry the error byte, the return delay time (address 5, x 2 us) is
honoured, the control table has EEPROM (persists over :meth:`BusEmulator.power_cycle`) and RAM
(reset at power-up) semantics, range/angle-limit/lock checks, the status return level, REG_WRITE +
ACTION, SYNC_WRITE and the alarm shutdown (an alarm in ``alarm_shutdown`` zeroes the torque limit;
writing a non-zero torque limit recovers once the cause is gone).

What the horns do is a *backend*:

* :class:`IdealServoBackend`: a servo that follows its goal at the moving speed (register 32;
  0 = the no-load speed) on the 1 kHz firmware grid, limp when torque is off;
* :class:`ServoBusBackend`: an adapter over any :class:`hexapod_model.bus.ServoBus` (the MuJoCo
  sim ``hexapod_sim.sim.HexapodSim``): goal writes become ``sync_write`` and position reads
  ``wait_until`` + ``read_position`` on that bus, with the robot description's mounting
  (direction, offset) between DH angle and raw tick.

Fault injection (:class:`Faults`): dropped replies, corrupt checksums, late (stale) replies ahead of
the real one, every reply held back by an adapter latency (:meth:`Faults.set_reply_latency`, the
FTDI latency timer), a servo that disappears,
overheating (temperature above the limit at address 11), overload, input voltage, and the whole
port vanishing (:meth:`BusEmulator.disconnect`) and coming back (:meth:`BusEmulator.reconnect`,
behind a stable symlink like a udev name). A servo whose baud rate register (address 4) does not
match the rate the host opened the port at (the pty's termios speed) does not answer, and the
status return level (address 16) is honoured as the e-manual defines it: 0 = status packets only
for PING, 1 = only for PING and READ, 2 = for every instruction (never for broadcasts).

The log (:attr:`BusEmulator.log`) keeps every instruction as received (``rx``), the bytes sent
back (``tx``, as corrupted or prefixed) and, without a reply, why (``note``).

Timing convention: emulator time is seconds since :meth:`BusEmulator.start` on its clock; the
firmware ticks at integer milliseconds of it; a goal takes effect at the first tick at or after
the instruction's arrival; a READ samples the position at the instruction's arrival (the start
of the transaction). With ``wire_time=True`` the reply is additionally held back by the wire time
of both packets at the configured baud rate (10 bits per byte), so round trips look like a real
1 Mbps bus; with ``wire_time=False`` only the return delay is applied.
"""
from __future__ import annotations

import argparse
import collections
import math
import os
import random
import select
import signal
import heapq
import sys
import termios
import threading
import time
import tty
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Protocol

from hexapod_model.bus import ServoBus
from hexapod_model.description import ALL_JOINTS, Robot, load_robot
from hexapod_model.servo import servo_theta, servo_tick

from . import protocol as p

AX12A_NO_LOAD_SPEED_RPM = 59.0     # e-manual: no-load speed at 12 V; the ideal servo's top speed


class EmulatorError(RuntimeError):
    """The emulator cannot do what was asked (bad servo id, pty failure, ...)."""


# ----------------------------------------------------------------------------- backends
class ServoBackend(Protocol):
    """What moves the servo horns. ``slot`` is the physical servo (index into ALL_JOINTS), ``t``
    emulator time [s]; ticks are raw servo ticks."""

    def goals(self, t: float, goals: Mapping[int, int]) -> None: ...

    def torque(self, t: float, slot: int, enabled: bool) -> None: ...

    def sample(self, t: float, slot: int) -> tuple[float, float]:
        """(present tick, signed speed in ticks/s) at time ``t``."""

    def status(self, slot: int) -> tuple[float | None, float | None]:
        """(temperature [deg C], load fraction) when the backend models them, else None."""


def firmware_tick_at_or_after(t: float, period: float) -> int:
    return int(math.ceil(t / period - 1e-9))


class IdealServoBackend:
    """Servos that move straight to their goal at a constant speed on the firmware grid.

    ``speed_ticks_per_s(slot)`` is asked at every goal write (the emulator passes the moving
    speed register). No gravity: a limp servo stays where it is.
    """

    def __init__(self, robot: Robot, initial_ticks: Mapping[int, float] | None = None):
        self.period = robot.servo.control_period_s
        self.max_tick = robot.servo.max_tick
        center = float(robot.servo.center_tick)
        n = len(ALL_JOINTS)
        init = dict(initial_ticks or {})
        self._pos = [float(init.get(s, center)) for s in range(n)]   # position at tick self._k
        self._k = [0] * n
        self._goal = list(self._pos)
        self._enabled = [False] * n
        self._rate = [0.0] * n                                       # ticks per firmware period
        self.speed_ticks_per_s: Callable[[int], float] = lambda slot: 0.0

    def _advance(self, slot: int, k: int) -> None:
        if k <= self._k[slot]:
            return
        if self._enabled[slot]:
            err = self._goal[slot] - self._pos[slot]
            step = self._rate[slot] * (k - self._k[slot])
            self._pos[slot] += math.copysign(min(abs(err), step), err)
        self._k[slot] = k

    def goals(self, t: float, goals: Mapping[int, int]) -> None:
        k = firmware_tick_at_or_after(t, self.period) - 1    # the old goal acts until tick k
        for slot, tick in goals.items():
            self._advance(slot, k)
            self._goal[slot] = float(tick)
            self._rate[slot] = self.speed_ticks_per_s(slot) * self.period

    def torque(self, t: float, slot: int, enabled: bool) -> None:
        self._advance(slot, firmware_tick_at_or_after(t, self.period) - 1)
        self._enabled[slot] = enabled
        self._rate[slot] = self.speed_ticks_per_s(slot) * self.period

    def sample(self, t: float, slot: int) -> tuple[float, float]:
        k = int(math.floor(t / self.period + 1e-9))
        self._advance(slot, k)
        moving = self._enabled[slot] and abs(self._goal[slot] - self._pos[slot]) > 0
        speed = math.copysign(self._rate[slot] / self.period, self._goal[slot] - self._pos[slot]) if moving else 0.0
        return self._pos[slot], speed

    def status(self, slot: int) -> tuple[float | None, float | None]:
        return None, None          # no thermal or load model: the emulator's own values apply


class ServoBusBackend:
    """Adapter: the emulated servos are the joints of a :class:`ServoBus` (e.g. the MuJoCo sim).

    Emulator time ``t`` maps to bus time ``t0 + t`` (``t0`` = the bus's ``now()`` when the adapter
    was made). A goal write is ``wait_until`` + ``sync_write``; a sample is ``wait_until`` +
    ``read_position``, which costs the bus its ``t_com_s`` (so a fast reader pushes a simulated
    bus ahead of wall time; it never runs behind). Torque enable is forwarded when the bus has
    ``set_torque_enabled(enabled, joints)`` (HexapodSim); otherwise the simulated servos stay
    powered. When the bus has ``servo_state()`` (HexapodSim), its temperatures and loads are what
    the emulated servos report, so the sim's thermal model can raise the overheating alarm.
    """

    def __init__(self, bus: ServoBus, robot: Robot):
        self.bus = bus
        self.robot = robot
        # Warm up before the clock starts: a JIT-compiled sim compiles on its first read/state
        # call, which must not happen while a driver waits for a reply.
        bus.read_position(ALL_JOINTS[0])
        if hasattr(bus, 'servo_state'):
            bus.servo_state()
        self.t0 = bus.now()
        self._joints = list(ALL_JOINTS)
        self._mount = [robot.bus.by_joint(j) for j in self._joints]
        self._last: dict[int, tuple[float, float]] = {}

    def goals(self, t: float, goals: Mapping[int, int]) -> None:
        self.bus.wait_until(self.t0 + t)
        self.bus.sync_write({self._joints[s]: float(servo_theta(tick, self.robot.servo, self._mount[s]))
                             for s, tick in goals.items()})

    def idle(self, t: float) -> None:
        """Keep the simulated bus in step with the emulator's clock while nobody talks to it."""
        self.bus.wait_until(self.t0 + t)

    def torque(self, t: float, slot: int, enabled: bool) -> None:
        setter = getattr(self.bus, 'set_torque_enabled', None)
        if setter is not None:
            self.bus.wait_until(self.t0 + t)
            setter(bool(enabled), [self._joints[slot]])

    def status(self, slot: int) -> tuple[float | None, float | None]:
        state = getattr(self.bus, 'servo_state', None)
        if state is None:
            return None, None
        st = state()
        return float(st.temperature_c[slot]), float(st.load_fraction[slot])

    def sample(self, t: float, slot: int) -> tuple[float, float]:
        self.bus.wait_until(self.t0 + t)
        theta, ts = self.bus.read_position(self._joints[slot])
        tick = float(servo_tick(theta, self.robot.servo, self._mount[slot]))
        speed = 0.0
        prev = self._last.get(slot)
        if prev is not None and ts > prev[1]:
            speed = (tick - prev[0]) / (ts - prev[1])
        self._last[slot] = (tick, ts)
        return tick, speed


# ----------------------------------------------------------------------------- servo
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


@dataclass
class LogEntry:
    """One instruction as the emulator saw it (for tests and the CLI's verbose mode)."""

    t: float              # emulator time of arrival [s]
    wall: float           # time.time() of arrival
    servo_id: int
    instruction: int
    address: int | None
    data: bytes
    replied: bool
    error: int
    wall_reply: float = float('nan')   # time.time() when the status packet was written
    t_reply: float = float('nan')      # emulator time when the status packet was written (clock of ``t``)
    reply_params: bytes = b''          # parameters of the status packet (the data of a READ)
    reply_delay_s: float = 0.0         # the servo's return delay time applied before replying
    rx: bytes = b''                    # the instruction packet exactly as received
    tx: bytes = b''                    # the bytes sent back (corrupted / with a stale packet ahead, as sent)
    note: str = ''                     # why there was no reply (status return level, baud mismatch, fault)


# ----------------------------------------------------------------------------- faults
class Faults:
    """Fault injection. Every method is thread-safe and takes effect on the next packet.

    ``ids`` = None means any servo. ``count`` faults happen on the next ``count`` matching
    replies; ``probability`` makes each matching reply fail at random (seeded).
    """

    def __init__(self, emulator: 'BusEmulator', seed: int):
        self._emu = emulator
        self._rng = random.Random(seed)
        self._drop: list[tuple[set[int] | None, int | None, float]] = []
        self._corrupt: list[tuple[set[int] | None, int | None, float]] = []
        self._stale: list[tuple[set[int] | None, int | None, float]] = []
        self.missing: set[int] = set()
        self.reply_latency_s = 0.0
        self.dropped = 0
        self.corrupted = 0
        self.stale = 0

    @staticmethod
    def _ids(ids) -> set[int] | None:
        if ids is None:
            return None
        return {int(ids)} if isinstance(ids, int) else {int(i) for i in ids}

    def drop_replies(self, ids=None, count: int | None = 1, probability: float = 1.0) -> None:
        """The next ``count`` replies (or each with ``probability`` if ``count`` is None) are lost."""
        with self._emu.lock:
            self._drop.append((self._ids(ids), count, probability))

    def corrupt_replies(self, ids=None, count: int | None = 1, probability: float = 1.0) -> None:
        """The next ``count`` replies get a wrong checksum byte."""
        with self._emu.lock:
            self._corrupt.append((self._ids(ids), count, probability))

    def stale_replies(self, ids=None, count: int | None = 1, probability: float = 1.0) -> None:
        """The next ``count`` replies are preceded by a stray empty status packet of the same servo, as
        when the reply to an earlier, timed-out instruction arrives late."""
        with self._emu.lock:
            self._stale.append((self._ids(ids), count, probability))

    def set_reply_latency(self, seconds: float) -> None:
        """Every reply reaches the host ``seconds`` later than the servo sent it, as behind an FTDI
        adapter whose latency timer is at its 16 ms default. Instructions are still executed on
        arrival (the host-to-servo direction is not held back)."""
        if not seconds >= 0:
            raise EmulatorError(f'reply latency must be >= 0, got {seconds}')
        with self._emu.lock:
            self.reply_latency_s = float(seconds)

    def remove_servo(self, servo_id: int) -> None:
        """The servo disappears from the bus (cable cut): it neither answers nor executes."""
        with self._emu.lock:
            self._emu.servo(servo_id)
            self.missing.add(servo_id)

    def restore_servo(self, servo_id: int) -> None:
        with self._emu.lock:
            self.missing.discard(servo_id)

    def set_temperature(self, servo_id: int, temperature_c: float) -> None:
        """Present temperature; above the limit (address 11) it raises the overheating alarm."""
        with self._emu.lock:
            s = self._emu.servo(servo_id)
            s.temperature_c = float(temperature_c)
            self._emu._check_alarms(s)

    def set_overload(self, servo_id: int, active: bool = True) -> None:
        """The servo cannot hold its load (overload alarm) until cleared."""
        with self._emu.lock:
            s = self._emu.servo(servo_id)
            s.overload = bool(active)
            self._emu._check_alarms(s)

    def set_voltage(self, voltage_v: float, servo_id: int | None = None) -> None:
        with self._emu.lock:
            for s in ([self._emu.servo(servo_id)] if servo_id is not None else self._emu.servos):
                s.voltage_v = float(voltage_v)

    def clear(self) -> None:
        """Remove every pending drop/corrupt rule and restore missing servos."""
        with self._emu.lock:
            self._drop.clear()
            self._corrupt.clear()
            self._stale.clear()
            self.missing.clear()

    @staticmethod
    def _match(rules, rng, servo_id) -> bool:
        for i, (ids, count, prob) in enumerate(rules):
            if ids is not None and servo_id not in ids:
                continue
            if rng.random() >= prob:
                continue
            if count is not None:
                if count <= 1:
                    del rules[i]
                else:
                    rules[i] = (ids, count - 1, prob)
            return True
        return False

    def _should_drop(self, servo_id: int) -> bool:
        if self._match(self._drop, self._rng, servo_id):
            self.dropped += 1
            return True
        return False

    def _should_prepend_stale(self, servo_id: int) -> bool:
        if self._match(self._stale, self._rng, servo_id):
            self.stale += 1
            return True
        return False

    def _should_corrupt(self, servo_id: int) -> bool:
        if self._match(self._corrupt, self._rng, servo_id):
            self.corrupted += 1
            return True
        return False


# ----------------------------------------------------------------------------- bus emulator
class BusEmulator:
    """18 AX-12A servos on a pseudo-terminal. Use as a context manager or start()/stop()."""

    def __init__(self, robot: Robot | None = None, backend: ServoBackend | None = None, *,
                 servo_ids: Mapping[str, int] | None = None, model_numbers: Mapping[int, int] | None = None,
                 absent_ids: tuple[int, ...] = (), link_path: str | os.PathLike | None = None,
                 wire_time: bool = False, ambient_c: float = 30.0, seed: int = 0,
                 clock: Callable[[], float] = time.monotonic, log_size: int = 100_000):
        self.robot = robot or load_robot()
        self.clock = clock
        self.wire_time = wire_time
        self.baud_rate = float(self.robot.bus.baud_rate)
        ids = {bj.joint: bj.servo_id for bj in self.robot.bus.joints}
        ids.update(servo_ids or {})
        unknown = set(servo_ids or {}) - set(ALL_JOINTS)
        if unknown:
            raise EmulatorError(f'servo_ids: unknown joint(s) {sorted(unknown)}')
        self.lock = threading.RLock()
        sv = self.robot.servo
        self._center = sv.center_tick
        self.servos: list[EmulatedServo] = []
        for slot, joint in enumerate(ALL_JOINTS):
            sid = ids[joint]
            if sid in absent_ids:
                continue
            self.servos.append(EmulatedServo(
                slot, sid, model_number=(model_numbers or {}).get(sid, p.AX12A_MODEL_NUMBER),
                temperature_limit_c=int(round(sv.shutdown_temperature_c)),
                supply_voltage_v=sv.supply_voltage_v, ambient_c=ambient_c))
        self.backend: ServoBackend = backend or IdealServoBackend(self.robot)
        if isinstance(self.backend, IdealServoBackend):
            self.backend.speed_ticks_per_s = self._speed_ticks_per_s
        self.faults = Faults(self, seed)
        self.log: collections.deque[LogEntry] = collections.deque(maxlen=log_size)
        self.link_path = Path(link_path) if link_path else None
        self._master: int | None = None
        self._slave: int | None = None
        self._slave_name = ''
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._t0 = 0.0
        self._parser = p.PacketParser()
        self.packets = 0
        self._late: list[tuple[float, int, bytes]] = []
        self._late_seq = iter(range(1 << 62))
        self._late_cv = threading.Condition()
        self._late_thread: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def port(self) -> str:
        """The path to open: the symlink when ``link_path`` was given, else the pty slave."""
        if self._master is None:
            raise EmulatorError('emulator is not started')
        return str(self.link_path) if self.link_path else self._slave_name

    def now(self) -> float:
        """Emulator time [s] (firmware ticks at its integer milliseconds)."""
        return self.clock() - self._t0

    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        self._master, self._slave = master, slave
        self._slave_name = os.ttyname(slave)
        self._parser = p.PacketParser()
        if self.link_path:
            tmp = self.link_path.with_name(self.link_path.name + '.tmp')
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self._slave_name)
            os.replace(tmp, self.link_path)

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def start(self) -> 'BusEmulator':
        """Open the pty and serve it from a background thread."""
        if self._thread is not None:
            raise EmulatorError('emulator already started')
        with self.lock:
            for s in self.servos:
                tick, _ = self.backend.sample(0.0, s.slot)
                s.power_up(present_tick=int(round(tick)))
        self._t0 = self.clock()
        self._open_pty()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name='ax12-bus-emulator', daemon=True)
        self._thread.start()
        self._late_thread = threading.Thread(target=self._deliver_late, name='ax12-late-replies', daemon=True)
        self._late_thread.start()
        return self

    def _deliver_late(self) -> None:
        """Write the replies held back by ``Faults.set_reply_latency`` when they are due."""
        while not self._stop.is_set():
            with self._late_cv:
                if not self._late:
                    self._late_cv.wait(0.05)
                    continue
                due, _seq, reply = self._late[0]
                left = due - self.clock()
                if left > 2e-4:
                    self._late_cv.wait(left - 1.5e-4)
                    continue
                heapq.heappop(self._late)
            _sleep_until(self.clock, due)
            fd = self._master
            if fd is not None:
                try:
                    os.write(fd, reply)
                except OSError:
                    pass

    def stop(self) -> None:
        self._stop.set()
        with self._late_cv:
            self._late_cv.notify_all()
        for th in (self._thread, self._late_thread):
            if th is not None:
                th.join(timeout=2.0)
        self._thread = self._late_thread = None
        self._close_pty()
        if self.link_path and self.link_path.is_symlink():
            self.link_path.unlink()

    def __enter__(self) -> 'BusEmulator':
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def disconnect(self) -> None:
        """The port vanishes (USB adapter unplugged): the pty closes, the driver gets I/O errors."""
        with self.lock:
            self._close_pty()
            if self.link_path and self.link_path.is_symlink():
                self.link_path.unlink()

    def reconnect(self) -> None:
        """The adapter is back: a new pty (behind ``link_path``, if given). Servos keep their state."""
        with self.lock:
            if self._master is not None:
                raise EmulatorError('emulator is connected already')
            self._open_pty()

    def power_cycle(self) -> None:
        """Servo power off/on: RAM back to power-up values, EEPROM kept (torque off, goal = present)."""
        with self.lock:
            t = self.now()
            for s in self.servos:
                tick, _ = self.backend.sample(t, s.slot)
                s.power_up(present_tick=int(round(tick)))
                self.backend.torque(t, s.slot, False)

    def line_baud(self) -> int | None:
        """Baud rate the driver set on the port (the pty's termios), or None when unknown."""
        if self._slave is None:
            return None
        try:
            speed = termios.tcgetattr(self._slave)[5]
        except (termios.error, OSError):
            return None
        return _TERMIOS_BAUD.get(speed)

    # ------------------------------------------------------------------ inspection
    def servo(self, servo_id: int) -> EmulatedServo:
        with self.lock:
            for s in self.servos:
                if s.servo_id == servo_id:
                    return s
        raise EmulatorError(f'no emulated servo with id {servo_id}')

    def servo_of_joint(self, joint: str) -> EmulatedServo:
        slot = ALL_JOINTS.index(joint)
        with self.lock:
            for s in self.servos:
                if s.slot == slot:
                    return s
        raise EmulatorError(f'no emulated servo for joint {joint!r}')

    def present_tick(self, servo_id: int, t: float | None = None) -> int:
        """Present position the servo would report now (or at emulator time ``t``)."""
        with self.lock:
            s = self.servo(servo_id)
            tick, _ = self.backend.sample(self.now() if t is None else t, s.slot)
            return min(self.robot.servo.max_tick, max(0, int(round(tick))))

    # ------------------------------------------------------------------ serving
    def _serve(self) -> None:
        while not self._stop.is_set():
            fd = self._master
            if fd is None:                       # disconnected: wait for reconnect()
                self._stop.wait(0.01)
                continue
            idle = getattr(self.backend, 'idle', None)
            try:
                ready, _, _ = select.select([fd], [], [], 0.005 if idle else 0.05)
            except (OSError, ValueError):
                continue
            if not ready:
                if idle is not None:
                    with self.lock:
                        idle(self.now())
                continue
            try:
                data = os.read(fd, 4096)
            except OSError:
                continue
            if not data:
                continue
            t_arrival = self.now()
            wall = time.time()
            replies = []
            with self.lock:
                for pkt in self._parser.feed(data):
                    self._reply_delay = 0.0
                    reply = self._handle(pkt, t_arrival, wall)
                    if reply is not None:
                        self.log[-1].reply_delay_s = self._reply_delay
                        replies.append((reply, self._reply_delay, len(pkt.params) + 6, self.log[-1]))
            for reply, delay, n_in, entry in replies:
                self._send(reply, t_arrival, delay, n_in, entry)

    def _send(self, reply: bytes, t_arrival: float, delay: float, n_instruction_bytes: int, entry: LogEntry) -> None:
        if self.wire_time:
            delay += (n_instruction_bytes + len(reply)) * p.BITS_PER_BYTE / self.baud_rate
        latency = self.faults.reply_latency_s
        if latency > 0:                          # delivered by the late-reply thread
            with self._late_cv:
                heapq.heappush(self._late, (self._t0 + t_arrival + delay + latency, next(self._late_seq), reply))
                self._late_cv.notify()
            return
        if delay > 0:
            _sleep_until(self.clock, self._t0 + t_arrival + delay)
        fd = self._master
        if fd is None:
            return
        # stamped before the write: a master that reads the log on receipt finds them set
        entry.t_reply, entry.wall_reply = self.now(), time.time()
        try:
            os.write(fd, reply)
        except OSError:
            pass

    _reply_delay = 0.0

    def _speed_ticks_per_s(self, slot: int) -> float:
        s = next(x for x in self.servos if x.slot == slot)
        units = s.get('moving_speed') & 0x3FF
        rpm = units * p.MOVING_SPEED_UNIT_RPM if units else AX12A_NO_LOAD_SPEED_RPM
        return rpm / 60.0 * self.robot.servo.ticks_per_range * 360.0 / self.robot.servo.range_deg

    def _check_alarms(self, s: EmulatedServo) -> int:
        """Apply the alarm shutdown for persistent errors; returns the persistent error bits."""
        bits = s.persistent_errors()
        if bits & s.get('alarm_shutdown') and s.get('torque_limit') != 0:
            s._put(p.REGISTERS['torque_limit'], 0)
            self.backend.torque(self.now(), s.slot, False)
        return bits

    def _refresh_present(self, s: EmulatedServo, t: float) -> None:
        tick, speed = self.backend.sample(t, s.slot)
        s._put(p.REGISTERS['present_position'], min(self.robot.servo.max_tick, max(0, int(round(tick)))))
        units = speed / (self.robot.servo.ticks_per_range * 360.0 / self.robot.servo.range_deg) * 60.0 \
            / p.MOVING_SPEED_UNIT_RPM
        s._put(p.REGISTERS['present_speed'], p.encode_speed(units))
        temp, load = self.backend.status(s.slot)
        if temp is not None:
            s.temperature_c = temp
        if load is None:
            load = 1.0 if s.overload else 0.0
        s._put(p.REGISTERS['present_load'], p.encode_load(max(-1.0, min(1.0, load)) if s.torque_on else 0.0))
        s._put(p.REGISTERS['present_voltage'], min(255, round(s.voltage_v / p.VOLTAGE_UNIT_V)))
        s._put(p.REGISTERS['present_temperature'], min(255, max(0, round(s.temperature_c))))
        s._put(p.REGISTERS['moving'], int(s.torque_on and abs(s.get('goal_position') - tick) >= 1))

    def _apply(self, s: EmulatedServo, values: Mapping[str, int], t: float, goals: dict[int, int]) -> None:
        was_on = s.torque_on
        for name, v in values.items():
            s._put(p.REGISTERS[name], v)
        if 'goal_position' in values or 'moving_speed' in values:
            goals[s.slot] = s.get('goal_position')
        self._check_alarms(s)
        if s.torque_on != was_on:
            self.backend.torque(t, s.slot, s.torque_on)

    def _servos_with_id(self, servo_id: int) -> list[EmulatedServo]:
        return [s for s in self.servos if s.servo_id == servo_id and servo_id not in self.faults.missing]

    def _handle(self, pkt: p.Packet, t: float, wall: float) -> bytes | None:
        """Execute one instruction packet; return the status packet to send (or None)."""
        self.packets += 1
        broadcast = pkt.servo_id == p.BROADCAST_ID
        targets = self.servos if broadcast else self._servos_with_id(pkt.servo_id)
        targets = [s for s in targets if s.servo_id not in self.faults.missing]
        address = pkt.params[0] if pkt.params else None
        entry = LogEntry(t=t, wall=wall, servo_id=pkt.servo_id, instruction=pkt.code, address=address,
                         data=bytes(pkt.params[1:]), replied=False, error=0,
                         rx=p.encode_instruction(pkt.servo_id, pkt.code, pkt.params) if pkt.checksum_ok else b'')
        self.log.append(entry)
        if not targets:
            entry.note = 'no servo with this id'
            return None
        line = self.line_baud()
        if line is not None:
            heard = [s for s in targets if _baud_matches(s.get('baud_rate'), line)]
            if len(heard) != len(targets):
                entry.note = f'baud mismatch: line at {line} baud'
            targets = heard
            if not targets:
                return None
        if not pkt.checksum_ok:
            if broadcast:
                return None
            s = targets[0]
            return self._status(s, p.ERR_CHECKSUM, b'', entry, reply_level=p.RETURN_PING_ONLY)
        goals: dict[int, int] = {}
        reply = None
        if pkt.code == p.SYNC_WRITE:
            if broadcast and len(pkt.params) >= 2:
                start, n = pkt.params[0], pkt.params[1]
                body = pkt.params[2:]
                if n > 0 and len(body) % (n + 1) == 0:
                    for k in range(0, len(body), n + 1):
                        for s in self._servos_with_id(body[k]):
                            err, values = s.validate_write(start, body[k + 1:k + 1 + n])
                            if not err:
                                self._apply(s, values, t, goals)
        elif pkt.code == p.ACTION:
            ran = False
            for s in targets:
                if s.pending is not None:
                    a, d = s.pending
                    s.pending = None
                    s._put(p.REGISTERS['registered'], 0)
                    err, values = s.validate_write(a, d)
                    if not err:
                        self._apply(s, values, t, goals)
                    ran = True
            if not broadcast:
                reply = self._status(targets[0], 0 if ran else p.ERR_INSTRUCTION, b'', entry)
        else:
            for s in targets:
                r = self._execute(s, pkt, t, goals, entry)
                if not broadcast:
                    reply = r
        if goals:
            self.backend.goals(t, goals)
        return reply

    def _execute(self, s: EmulatedServo, pkt: p.Packet, t: float, goals: dict[int, int], entry: LogEntry):
        code, prm = pkt.code, pkt.params
        if code == p.PING:
            return self._status(s, 0, b'', entry, reply_level=p.RETURN_PING_ONLY)
        if code == p.READ:
            if len(prm) != 2:
                return self._status(s, p.ERR_INSTRUCTION, b'', entry, reply_level=p.RETURN_READ_ONLY)
            a, n = prm
            if n == 0 or a + n > p.TABLE_SIZE:
                return self._status(s, p.ERR_RANGE, b'', entry, reply_level=p.RETURN_READ_ONLY)
            if a + n > 36 and a < 47:
                self._refresh_present(s, t)
            return self._status(s, 0, bytes(s.mem[a:a + n]), entry, reply_level=p.RETURN_READ_ONLY)
        if code in (p.WRITE, p.REG_WRITE):
            if len(prm) < 2:
                return self._status(s, p.ERR_INSTRUCTION, b'', entry)
            err, values = s.validate_write(prm[0], bytes(prm[1:]))
            if not err:
                if code == p.WRITE:
                    old_limit = s.get('torque_limit')
                    self._apply(s, values, t, goals)
                    if 'torque_limit' in values and values['torque_limit'] and old_limit == 0:
                        self._check_alarms(s)        # recovery only sticks once the cause is gone
                else:
                    s.pending = (prm[0], bytes(prm[1:]))
                    s._put(p.REGISTERS['registered'], 1)
            return self._status(s, err, b'', entry)
        if code == p.RESET:
            s.mem[:p.EEPROM_END] = s.factory_eeprom
            s._put(p.REGISTERS['id'], 1)
            tick, _ = self.backend.sample(t, s.slot)
            s.power_up(present_tick=int(round(tick)))
            self.backend.torque(t, s.slot, False)
            return self._status(s, 0, b'', entry)
        return self._status(s, p.ERR_INSTRUCTION, b'', entry)

    def _status(self, s: EmulatedServo, err: int, params: bytes, entry: LogEntry,
                reply_level: int = p.RETURN_ALL) -> bytes | None:
        error = err | self._check_alarms(s)
        entry.error = error
        if s.get('status_return_level') < reply_level:
            entry.note = f'status return level {s.get("status_return_level")}: no status packet'
            return None
        if self.faults._should_drop(s.servo_id):
            entry.note = 'reply dropped (fault injection)'
            return None
        pkt = bytearray(p.encode_status(s.servo_id, error, params))
        if self.faults._should_corrupt(s.servo_id):
            pkt[-1] ^= 0x5A
        if self.faults._should_prepend_stale(s.servo_id):
            pkt[:0] = p.encode_status(s.servo_id, 0)
        entry.replied = True
        entry.reply_params = bytes(params)
        entry.tx = bytes(pkt)
        self._reply_delay = s.get('return_delay_time') * p.RETURN_DELAY_UNIT_S
        return bytes(pkt)


_TERMIOS_BAUD = {getattr(termios, f'B{b}'): b for b in (
    9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000, 1500000,
    2000000, 2500000, 3000000, 3500000, 4000000) if hasattr(termios, f'B{b}')}


def _baud_matches(register_value: int, line_baud: float) -> bool:
    """A servo at register-4 rate hears the line only within the UART tolerance (about 3 %);
    otherwise it sees framing errors and garbage and does not answer."""
    return abs(p.baud_of_register(register_value) - line_baud) <= 0.03 * line_baud


def _sleep_until(clock: Callable[[], float], deadline: float) -> None:
    """Sleep until ``clock() >= deadline``; the last ~150 us are spun for sub-ms precision."""
    while True:
        left = deadline - clock()
        if left <= 0:
            return
        if left > 2e-4:
            time.sleep(left - 1.5e-4)


# ----------------------------------------------------------------------------- command line
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog='bus_emulator',
        description='Emulated AX-12A bus (Dynamixel Protocol 1.0) on a pseudo-terminal: prints the port path, '
                    'serves until Ctrl-C. Point the driver at it: ros2 run hexapod_driver driver_node '
                    '--ros-args -p device:=<path>.')
    ap.add_argument('--robot', default=None, help='robot description YAML (default: the packaged robot.yaml)')
    ap.add_argument('--link', default=None,
                    help='also create this symlink to the pty (a stable name, like a udev symlink)')
    ap.add_argument('--backend', choices=['ideal', 'sim'], default='ideal',
                    help='ideal: servos move straight to their goals; sim: the MuJoCo hexapod '
                         '(hexapod_sim.sim.HexapodSim) moves them, in step with wall-clock time')
    ap.add_argument('--terrain', default='flat', help='sim backend: terrain name')
    ap.add_argument('--fixed-base', action='store_true', help='sim backend: trunk fixed in the air')
    ap.add_argument('--wire-time', action='store_true',
                    help='delay replies by the 1 Mbps wire time of both packets (10 bits/byte)')
    ap.add_argument('--absent', type=int, nargs='*', default=[], help='servo IDs that are not on the bus')
    ap.add_argument('--drop-probability', type=float, default=0.0, help='lose each reply with this probability')
    ap.add_argument('--corrupt-probability', type=float, default=0.0,
                    help='corrupt the checksum of each reply with this probability')
    ap.add_argument('--reply-latency-ms', type=float, default=0.0,
                    help='hold every reply back this long, like an FTDI adapter with its 16 ms default latency timer')
    ap.add_argument('--servo-baud', type=int, default=None,
                    help='baud rate register (address 4) of every servo, e.g. 34 for 57600 baud; a servo answers '
                         'only when the port is opened at its rate')
    ap.add_argument('--status-return-level', type=int, choices=[0, 1, 2], default=None,
                    help='status return level (address 16) of every servo: 0 PING only, 1 reads only, 2 all')
    ap.add_argument('--seed', type=int, default=0, help='seed of the random faults')
    ap.add_argument('--verbose', action='store_true', help='print every instruction packet (slow)')
    args = ap.parse_args(argv)
    for name in ('drop_probability', 'corrupt_probability'):
        v = getattr(args, name)
        if not 0.0 <= v <= 1.0:
            ap.error(f'--{name.replace("_", "-")} must be within 0..1, got {v}')
    robot = load_robot(args.robot)
    backend = None
    if args.backend == 'sim':
        from hexapod_sim.sim import HexapodSim     # optional: only this backend needs MuJoCo
        backend = ServoBusBackend(HexapodSim(robot, terrain=args.terrain, fixed_base=args.fixed_base), robot)
    emu = BusEmulator(robot, backend, link_path=args.link, wire_time=args.wire_time, absent_ids=tuple(args.absent),
                      seed=args.seed)
    if args.drop_probability:
        emu.faults.drop_replies(count=None, probability=args.drop_probability)
    if args.corrupt_probability:
        emu.faults.corrupt_replies(count=None, probability=args.corrupt_probability)
    if args.reply_latency_ms < 0:
        ap.error(f'--reply-latency-ms must be >= 0, got {args.reply_latency_ms}')
    emu.faults.set_reply_latency(args.reply_latency_ms / 1000.0)
    if args.servo_baud is not None and not 0 <= args.servo_baud <= 254:
        ap.error(f'--servo-baud is register 4 (0..254), got {args.servo_baud}')
    for s in emu.servos:
        if args.servo_baud is not None:
            s.set_register('baud_rate', args.servo_baud)
        if args.status_return_level is not None:
            s.set_register('status_return_level', args.status_return_level)
    emu.start()
    ids = sorted(s.servo_id for s in emu.servos)
    print(f'AX-12A bus emulator: {len(ids)} servos (ids {ids}) on {emu.port}', flush=True)
    if args.link:
        print(f'pty: {emu._slave_name}', flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.2):
            while args.verbose and emu.log:
                e = emu.log.popleft()
                print(f'{e.t:10.4f} id={e.servo_id:3d} {p.INSTRUCTION_NAMES.get(e.instruction, hex(e.instruction))}'
                      f' addr={e.address} data={e.data.hex(" ")} err={e.error:#04x}'
                      f'{" reply=" + e.reply_params.hex(" ") if e.replied else " (no reply: " + e.note + ")"}'
                      f' rx={e.rx.hex(" ")} tx={e.tx.hex(" ")}', flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        print(f'served {emu.packets} packets', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
