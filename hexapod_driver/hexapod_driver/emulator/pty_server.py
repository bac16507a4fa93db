"""The emulated bus itself: :class:`BusEmulator` serves 18 AX-12A servos on a pseudo-terminal
(packet parsing, status replies, return delay and wire time, alarms, disconnect/reconnect,
power cycle) and keeps a :class:`LogEntry` per instruction. The package docstring
(:mod:`hexapod_driver.emulator`) describes the behaviour and the timing convention."""
from __future__ import annotations

import collections
import heapq
import math
import os
import select
import termios
import threading
import time
import tty
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

from hexapod_driver import protocol as p
from hexapod_driver.emulator.backends import IdealServoBackend, ServoBackend
from hexapod_driver.emulator.control_table import EmulatedServo, EmulatorError
from hexapod_driver.emulator.faults import Faults
from hexapod_model.description import ALL_JOINTS, Robot, load_robot

AX12A_NO_LOAD_SPEED_RPM = 59.0     # e-manual: no-load speed at 12 V; the ideal servo's top speed


@dataclass(slots=True)
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
    wall_reply: float = float('nan')   # time.time() when the status packet was written (held back by the
                                       # adapter latency or a stall: when it was written to the host)
    t_reply: float = float('nan')      # emulator time when the status packet was written (clock of ``t``)
    reply_params: bytes = b''          # parameters of the status packet (the data of a READ)
    reply_delay_s: float = 0.0         # the servo's return delay time applied before replying
    rx: bytes = b''                    # the instruction packet exactly as received
    tx: bytes = b''                    # the bytes sent back (corrupted / with a stale packet ahead, as sent)
    note: str = ''                     # why there was no reply (status return level, baud mismatch, fault)
    corrupted: bool = False            # the reply was sent with a broken checksum (fault injection)


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
        self._late: list[tuple[float, int, bytes, LogEntry]] = []     # (due, order, reply, its log entry)
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
        """Write the replies held back (``Faults.set_reply_latency``, ``Faults.hold_replies``) when
        they are due, in order."""
        while not self._stop.is_set():
            with self._late_cv:
                if not self._late:
                    self._late_cv.wait(0.05)
                    continue
                due, _seq, reply, entry = self._late[0]
                left = due - self.clock()
                if left > 2e-4:
                    self._late_cv.wait(left - 1.5e-4)
                    continue
            _sleep_until(self.clock, due)
            fd = self._master
            if fd is not None:
                entry.t_reply, entry.wall_reply = self.now(), time.time()     # as in _send: before the write
                try:
                    os.write(fd, reply)
                except OSError:
                    pass
            with self._late_cv:            # queued until written: a reply due at once cannot overtake it
                heapq.heappop(self._late)

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
                ready, _, _ = select.select([fd], [], [], 0.0005 if idle else 0.05)
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
                    self._reply_delay = self._reply_hold = 0.0
                    reply = self._handle(pkt, t_arrival, wall)
                    if reply is not None:
                        self.log[-1].reply_delay_s = self._reply_delay
                        replies.append((reply, self._reply_delay, self._reply_hold, len(pkt.params) + 6,
                                        self.log[-1]))
            for reply, delay, hold, n_in, entry in replies:
                self._send(reply, t_arrival, delay, hold, n_in, entry)

    def _send(self, reply: bytes, t_arrival: float, delay: float, hold: float, n_instruction_bytes: int,
              entry: 'LogEntry') -> None:
        if self.wire_time:
            delay += (n_instruction_bytes + len(reply)) * p.BITS_PER_BYTE / self.baud_rate
        latency = self.faults.reply_latency_s + hold
        with self._late_cv:
            # delivered by the late-reply thread, in order (a FIFO): a reply due at once waits too
            # while one before it is held back
            if latency > 0 or self._late:
                self._last_due = max(self._t0 + t_arrival + delay + latency, self._last_due)
                heapq.heappush(self._late, (self._last_due, next(self._late_seq), reply, entry))
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
    _reply_hold = 0.0
    _last_due = -math.inf

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

    def _refresh_present(self, s: EmulatedServo, t: float, status: bool = True) -> None:
        """The present_* registers at ``t``. ``status``: also load and temperature, which the backend
        computes for every servo at once (a sim's whole servo state): only when a read covers them,
        so a position read, the driver's most frequent transaction, is answered sooner."""
        tick, speed = self.backend.sample(t, s.slot)
        s._put(p.REGISTERS['present_position'], min(self.robot.servo.max_tick, max(0, int(round(tick)))))
        units = speed / (self.robot.servo.ticks_per_range * 360.0 / self.robot.servo.range_deg) * 60.0 \
            / p.MOVING_SPEED_UNIT_RPM
        s._put(p.REGISTERS['present_speed'], p.encode_speed(units))
        if status:
            temp, load = self.backend.status(s.slot)
            if temp is not None:
                s.temperature_c = temp
            s.temperature_c = self.faults.temperature_override.get(s.servo_id, s.temperature_c)
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
                self._refresh_present(s, t, status=a + n > 40 and a < 44)
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
            entry.corrupted = True
        if self.faults._should_prepend_stale(s.servo_id):
            pkt[:0] = p.encode_status(s.servo_id, 0)
        self._reply_hold = self.faults._hold_s(s.servo_id, entry.address)
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
