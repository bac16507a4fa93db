"""The driver core: one AX-12A bus through dynamixel-sdk, without any ROS import.

:class:`DynamixelBus` owns the dynamixel-sdk ``PortHandler``/``PacketHandler`` (Protocol 1.0) and
one lock that every bus transaction takes. It

* verifies at start-up that every joint's servo answers a PING and reports model number 12
  (:class:`ServoVerificationError` names each missing or wrong servo), then configures return
  delay time, angle limits (from the joint limits), alarm shutdown, and every register of the servo
  law from the robot description (compliance margin and slope, moving speed, punch) plus the torque
  limit, sets each goal to the present position and enables torque (no jump at start-up);
* implements the :class:`hexapod_model.bus.ServoBus` protocol (``now``, ``sync_write``,
  ``read_position``, ``wait_until``), so the locomotion library can run on it directly;
* runs the bus loop one :meth:`DynamixelBus.step` at a time for the ROS node: pending goals are
  sync-written, then the next joint of the read schedule is read, and diagnostics are read
  interleaved (one servo per step) so they never block the position reads for long;
* validates commands (unknown joint, NaN/inf, outside the joint limits: clamped or rejected by
  policy; stale stamps rejected; no fresh command for ``command_timeout_s``: hold position);
* survives a flaky or vanished port: each read is retried within a budget, a servo that stops
  answering is reported and only re-probed periodically, a lost port is reopened, re-verified
  and re-configured; a position is only ever reported when a servo returned it.

Stamps: the sample time of a read is the time its instruction packet was written to the port
(the start of the transaction), taken from the injected ``clock``; T_com is the time from that
write to the complete status packet.
"""
from __future__ import annotations

import contextlib
import math
import os
import select
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np
import serial
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler

from hexapod_driver import protocol as p
from hexapod_driver.config import DriverConfig
from hexapod_driver.port import LowLatencyPortHandler, in_waiting, write_all
from hexapod_driver.timing import TimingStats
from hexapod_model.bus import BusError
from hexapod_model.description import ALL_JOINTS, BusJoint, DescriptionError, Robot, parse_joint_name
from hexapod_model.servo import servo_theta, servo_tick

ALARM_BITS = p.ERR_OVERHEATING | p.ERR_OVERLOAD
CLOCK_JUMP_S = 0.05                   # a clock going back by more than this has jumped (sim reset, clock set)
CLOCK_PAUSE_S = 2.0                   # wall seconds without the clock advancing before it is called paused
TORQUE_OFF_REOPEN_S = 1.0             # how long a torque-off (exit, emergency stop) tries to reopen a lost port
DIAG_START = 24                       # torque_enable .. moving in one READ
DIAG_LEN = 46 - DIAG_START + 1


class ServoVerificationError(BusError):
    """Start-up found servos that do not answer or are not AX-12As; ``missing``/``wrong`` list them."""

    def __init__(self, message: str, missing: Sequence[tuple[str, int]] = (),
                 wrong: Sequence[tuple[str, int, int]] = ()):
        super().__init__(message)
        self.missing = list(missing)
        self.wrong = list(wrong)


class CommandError(ValueError):
    """A command or read schedule was rejected; the message names the joint and the reason."""


class PortLostError(BusError):
    """The serial port vanished or failed (unplugged adapter, I/O error)."""


# ----------------------------------------------------------------------------- data types
@dataclass(frozen=True)
class Sample:
    """One position read: what the servo returned, stamped at the start of the transaction."""

    joint: str
    theta_rad: float
    tick: int
    stamp: float          # time the READ instruction was written [s, driver clock]
    t_com_s: float        # duration of the transaction (write to complete status packet)
    error_bits: int


@dataclass
class ServoState:
    """What the driver knows about one servo (the ServoStatus message)."""

    joint: str
    servo_id: int
    responding: bool = True
    missing: bool = False
    consecutive_failures: int = 0
    last_probe: float = -math.inf
    error_bits: int = 0
    torque_enabled: bool = False
    torque_limit: int | None = 0    # register 34 as last read (None: unknown)
    temperature_c: float = math.nan
    voltage_v: float = math.nan
    load_fraction: float = math.nan
    present_tick: int | None = None
    failed_attempts: int = 0        # read attempts without a valid reply, since start-up
    faulted: int = 0                # alarm bits that triggered the fault policy (0 = no fault)
    message: str = ''


@dataclass
class StepResult:
    """What one bus-loop step produced, for the node to publish."""

    samples: list[Sample] = field(default_factory=list)
    diagnostics: list[ServoState] | None = None
    events: list[tuple[str, str]] = field(default_factory=list)    # (level, text): 'info'|'warn'|'error'
    wrote: bool = False


# ----------------------------------------------------------------------------- the driver core
class DynamixelBus:
    """The AX-12A bus. Thread-safe: every transaction holds :attr:`lock`."""

    def __init__(self, robot: Robot, config: DriverConfig = DriverConfig(), *,
                 clock: Callable[[], float] = time.time, sleep: Callable[[float], None] = time.sleep,
                 t_com_s: float | None = None):
        config.validate()
        self.robot = robot
        self.config = config
        self.clock = clock
        self._sleep = sleep
        self.t_com_s = robot.bus.t_com_s if t_com_s is None else float(t_com_s)
        self.baud_rate = int(robot.bus.baud_rate)
        self.mount: dict[str, BusJoint] = {j.joint: j for j in robot.bus.joints}   # the description's mounting
        self.joints = tuple(ALL_JOINTS)
        self.margin = robot.servo.compliance_margin_ticks    # the model's servo law assumes these
        self.slope = robot.servo.compliance_slope_ticks
        self.punch = robot.servo.punch
        self.moving_speed = robot.servo.moving_speed
        self.lock = threading.RLock()
        self.packet = PacketHandler(1.0)
        self.port: LowLatencyPortHandler | None = None
        self.port_ok = False
        self.states = {j: ServoState(j, self.mount[j].servo_id) for j in self.joints}
        self.goals_tick: dict[str, int] = {}
        self.timing = TimingStats()
        self.estopped = False
        self._cmd_lock = threading.Lock()
        self._cmd_event = threading.Event()        # set when goals are pending
        self._pending: dict[str, int] = {}
        self._last_command_t: float | None = None
        self._holding = False
        self._schedule: tuple[str, ...] = self.joints
        self._cursor = 0
        self._next_read_t = -math.inf
        self._diag_queue: list[str] = []
        self._next_diag_t = -math.inf
        self._next_reconnect_t = -math.inf
        self._events: deque[tuple[str, str]] = deque(maxlen=1000)
        self._last_read: tuple[float, float, int] = (math.nan, math.nan, 0)
        self._packets: dict[tuple, bytes] = {}     # encoded READ instructions (the hot path)
        self._rx = bytearray()                     # received, not yet consumed bytes
        self.stale_bytes = 0                       # bytes discarded as not answering the request
        self._startup_attempts: int | None = None  # attempts per transaction while starting up
        self.last_ok_t = -math.inf                 # clock() of the last answered transaction (watchdog)
        self.last_failure = ''
        self.reply_latency_s = math.nan            # measured at start-up (median PING round trip - wire)
        self._closed_report: tuple[bool, str] | None = None
        self._loss_reported = False                # the loss of the port now lost was reported
        self._clock_seen: tuple[float, float] | None = None   # (clock, monotonic wall time) it last changed
        self._clock_paused = False
        self._throttle: dict[str, list] = {}       # key -> [window start, suppressed count, level, last text]
        self.throttle_s = 5.0

    # ------------------------------------------------------------------ conversions
    def to_tick(self, joint: str, theta_rad: float) -> int:
        t = servo_tick(theta_rad, self.robot.servo, self.mount[joint])
        return int(min(self.robot.servo.max_tick, max(0, round(t))))

    def to_theta(self, joint: str, tick: float) -> float:
        return float(servo_theta(tick, self.robot.servo, self.mount[joint]))

    def angle_limits_tick(self, joint: str) -> tuple[int, int]:
        """(CW, CCW) angle limits in raw ticks of the joint limits (mounting direction applied)."""
        lo, hi = self.robot.joint_limits(joint)
        a, b = self.to_tick(joint, lo), self.to_tick(joint, hi)
        return min(a, b), max(a, b)

    # ------------------------------------------------------------------ ServoBus protocol
    def now(self) -> float:
        return self.clock()

    @property
    def next_read_t(self) -> float:
        """When :meth:`step` may read next (read pacing, ``read_period_s``); -inf without pacing."""
        return self._next_read_t if self.config.read_period_s > 0 else -math.inf

    def wait_until(self, t: float) -> None:
        while True:
            left = t - self.clock()
            if left <= 0:
                return
            self._sleep(min(left, 0.05))

    def sync_write(self, goals_rad: Mapping[str, float]) -> float:
        """Validate and write goals at once (one SYNC_WRITE); returns the write time."""
        if self.estopped:
            raise CommandError('emergency stop is active: torque is off; restart the driver to re-enable')
        goals = self.validate_goals(goals_rad).goals_tick
        with self.lock:
            try:
                return self._sync_write_ticks(goals)
            except PortLostError as exc:
                self._port_lost(exc)
                raise

    def read_position(self, joint: str) -> tuple[float, float]:
        """Read one joint: (theta [rad], sample time). Raises BusError after the retry budget."""
        self._check_joint(joint)
        with self.lock:
            try:
                s = self._read_joint(joint, retries=self.config.read_retries)
            except PortLostError as exc:
                self._port_lost(exc)
                raise
        if s is None:
            raise BusError(f'{joint} (id {self.mount[joint].servo_id}): no valid reply after '
                           f'{1 + self.config.read_retries} attempts ({self.states[joint].message})')
        return s.theta_rad, s.stamp

    # ------------------------------------------------------------------ start-up
    def start(self) -> None:
        """Open the port, verify all servos, configure them and enable torque."""
        with self.lock:
            self._open()
            with self._startup_timeouts():
                self.verify()
                self.configure()

    @contextlib.contextmanager
    def _startup_timeouts(self):
        """Start-up: a longer reply timeout and ``startup_attempts`` tries per transaction."""
        port = self.port
        port.margin_ms = max(self.config.timeout_margin_ms, self.config.startup_timeout_margin_ms)
        self._startup_attempts = self.config.startup_attempts
        try:
            yield
        finally:
            self._startup_attempts = None
            if self.port is not None:
                self.port.margin_ms = self.config.timeout_margin_ms

    def _open(self) -> None:
        self._close_port()
        port = LowLatencyPortHandler(self.config.device, self.config.latency_timer_ms,
                                     self.config.timeout_margin_ms, clock=self.clock)
        try:
            if not port.setBaudRate(self.baud_rate):
                raise PortLostError(f'{self.config.device}: baud rate {self.baud_rate} is not supported '
                                    f'by the port handler')
        except (serial.SerialException, OSError) as exc:
            raise PortLostError(f'cannot open {self.config.device}: {exc}') from None
        self.port = port
        self.port_ok = True
        self._loss_reported = False

    def _close_port(self) -> None:
        if self.port is not None and self.port.ser is not None:
            try:
                self.port.closePort()
            except (serial.SerialException, OSError):
                pass
        self.port = None
        self.port_ok = False

    def verify(self) -> None:
        """PING every joint's servo and check its model number; raise naming every bad one.

        Also measures the reply latency (median PING round trip minus its wire time); replies far
        later than the wire time mean the USB adapter's latency timer is not 1 ms: the reply
        timeout is widened to cover it (so no reply is declared lost and then taken for the answer
        to a later request) and a warning says what to fix."""
        missing, wrong, rtts = [], [], []
        attempts = self._attempts(None)
        for j in self.joints:
            sid = self.mount[j].servo_id
            model, result, why = None, None, ''
            for _ in range(attempts):
                model, result, why = self._ping(sid, rtts)
                if result == COMM_SUCCESS:
                    break
            if result != COMM_SUCCESS:
                missing.append((j, sid, why))
            elif model != p.AX12A_MODEL_NUMBER:
                wrong.append((j, sid, model))
        if missing or wrong:
            parts = []
            if len(missing) == len(self.joints):
                parts.append(
                    f'no servo answers at {self.baud_rate} baud (tried ids '
                    f'{", ".join(str(i) for _j, i, _w in missing)}, {attempts} attempts each). Check the servo '
                    f'power and cable; if the servos are set to another baud rate (register 4), find them with '
                    f'`./hexapod run hexapod_driver servo_tool --device {self.config.device} --baud <rate> scan` '
                    f'(AX-12A rates: 1000000 factory default, 500000, 400000, 250000, 200000, 117647, 57600, '
                    f'19200, 9600) and set bus.baud_rate in the robot description (an overlay) to match')
            elif missing:
                parts.append('no answer from ' + ', '.join(
                    f'{j} (id {i})' + (f' [{w}]' if w else '') for j, i, w in missing))
            if wrong:
                parts.append('wrong model: ' + ', '.join(
                    f'{j} (id {i}) reports model number {m}, expected {p.AX12A_MODEL_NUMBER} (AX-12A)'
                    for j, i, m in wrong))
            raise ServoVerificationError(f'servo verification on {self.config.device} failed: ' + '; '.join(parts),
                                         [(j, i) for j, i, _w in missing], wrong)
        self._check_latency(rtts)

    def _check_latency(self, rtts: list[float]) -> None:
        if not rtts:
            return
        wire = 12 * p.BITS_PER_BYTE / self.baud_rate            # PING: 6 bytes out, 6 back
        late = max(0.0, float(np.median(rtts)) - wire)
        self.reply_latency_s = late
        if late * 1e3 > max(2.0, 2.0 * self.config.latency_timer_ms + 1.0):
            port = self.port
            needed_ms = late * 1e3 + 1.0
            old = port.latency_timer_ms
            port.latency_timer_ms = max(old, needed_ms / 2.0)       # the timeout counts it twice
            self._event('warn', f'replies arrive ~{late * 1e3:.0f} ms late (median PING round trip '
                                f'{(late + wire) * 1e3:.1f} ms, wire time {wire * 1e6:.0f} us): the USB adapter\'s '
                                f'latency timer is probably at its 16 ms default. Set the adapter\'s latency_timer to '
                                f'1 (udev rule, see docs/real-robot.md). Until then every read waits for it: reply '
                                f'timeout widened from latency_timer_ms={old:g} to {port.latency_timer_ms:.1f}')

    def _ping(self, sid: int, rtts: list[float] | None = None) -> tuple[int | None, int, str]:
        """PING, then READ the model number: (model, result, what failed)."""
        _data, result, _err = self._transact(sid, p.PING, [], 0)
        if result != COMM_SUCCESS:
            return None, result, f'PING: {_result_text(result)}'
        if rtts is not None:
            rtts.append(self.clock() - self.port.last_tx_time)
        data, result, _err = self._transact(sid, p.READ, [0, 2], 2)
        if result == COMM_RX_TIMEOUT:
            # answers PING but not READ: status return level 0. Set it to 2 (EEPROM; the write
            # itself is not answered at level 0) and ask again.
            self._transact(sid, p.WRITE, [16, p.RETURN_ALL], 0, expect_reply=False)
            self._event('warn', f'servo id {sid} answers PING but not READ (status return level 0?): '
                                f'status return level (address 16) set to {p.RETURN_ALL}')
            data, result, _err = self._transact(sid, p.READ, [0, 2], 2)
        if result != COMM_SUCCESS:
            return None, result, f'READ of the model number: {_result_text(result)}'
        self.last_ok_t = self.clock()
        return _u16(data), COMM_SUCCESS, ''

    def configure(self, enable_torque: bool = True) -> None:
        """Configure every servo, hold it at its present position and enable torque."""
        shutdown = ALARM_BITS
        for j in self.joints:
            sid = self.mount[j].servo_id
            self._ensure_status_return_level(j)
            self._ensure_eeprom(j, 'return_delay_time', self.config.return_delay_time)
            self._ensure_eeprom(j, 'alarm_shutdown', shutdown)
            if self.config.write_angle_limits:
                cw, ccw = self.angle_limits_tick(j)
                old = self._read_raw(j, 6, 4)
                if old is None:
                    raise BusError(f'{j} (id {sid}): cannot read the angle limits (address 6): {self.last_failure}')
                if (_u16(old[:2]), _u16(old[2:])) != (cw, ccw):       # both in one write: never cw > ccw
                    self._write(j, 6, _word(cw) + _word(ccw))
            self._write(j, 26, [self.margin, self.margin, self.slope, self.slope])
            self._write(j, 32, _word(self.moving_speed))
            self._write(j, 34, _word(self.config.torque_limit))
            self._write(j, 48, _word(self.punch))
            data = self._read_raw(j, 36, 2)
            if data is None:
                raise BusError(f'{j} (id {sid}): cannot read the present position during configuration: '
                               f'{self.last_failure}')
            tick = _u16(data)
            lo, hi = self.angle_limits_tick(j) if self.config.write_angle_limits else (0, self.robot.servo.max_tick)
            goal = min(hi, max(lo, tick))
            if goal != tick:
                self._event('warn', f'{j} (id {sid}) is at tick {tick}, outside its angle limits [{lo}, {hi}]: '
                                    f'goal set to {goal}, the joint will move there')
            self._write(j, 30, _word(goal))
            self._write(j, 24, [int(enable_torque)])
            self.goals_tick[j] = goal
            st = self.states[j]
            st.present_tick, st.torque_enabled, st.torque_limit = tick, enable_torque, self.config.torque_limit
            st.responding, st.missing, st.consecutive_failures, st.faulted = True, False, 0, 0
            st.message = 'configured' if enable_torque else 'configured, torque off (emergency stop)'

    def _ensure_status_return_level(self, joint: str) -> None:
        """Status return level (address 16) = 2, so that every write is answered and confirmed.

        At level 1 a servo answers only READ (and PING); at 0 only PING. The write that raises the
        level is therefore not answered: it is sent without waiting and checked by reading back."""
        sid = self.mount[joint].servo_id
        data = self._read_raw(joint, 16, 1)
        if data is None:
            raise BusError(f'{joint} (id {sid}): cannot read the status return level (address 16): '
                           f'{self.last_failure}')
        if data[0] == p.RETURN_ALL:
            return
        for _ in range(self._attempts(None)):
            self._transact(sid, p.WRITE, [16, p.RETURN_ALL], 0, expect_reply=False)
            self._sleep(0.002)                       # an unanswered EEPROM write: give it time
            back = self._read_raw(joint, 16, 1)
            if back is not None and back[0] == p.RETURN_ALL:
                self._event('warn', f'{joint} (id {sid}): status return level was {data[0]} '
                                    f'({"replies to PING only" if data[0] == 0 else "replies to reads only"}); '
                                    f'set to {p.RETURN_ALL} (EEPROM) so that every write is confirmed')
                return
        raise BusError(f'{joint} (id {sid}): status return level is {data[0]} and could not be set to '
                       f'{p.RETURN_ALL} (address 16): {self.last_failure or "read back a different value"}')

    def _ensure_eeprom(self, joint: str, name: str, value: int) -> None:
        r = p.register(name)
        data = self._read_raw(joint, r.address, r.size)
        if data is None:
            raise BusError(f'{joint} (id {self.mount[joint].servo_id}): cannot read {name} (address {r.address}): '
                           f'{self.last_failure}')
        if int.from_bytes(bytes(data), 'little') != value:      # write EEPROM only when it differs
            self._write(joint, r.address, list(int(value).to_bytes(r.size, 'little')))

    # ------------------------------------------------------------------ low-level transactions
    def _transact(self, sid: int, instruction: int, params: list[int], n_reply: int,
                  expect_reply: bool = True) -> tuple[bytes, int, int]:
        """One instruction/status exchange: (data, result, error); result is a dynamixel-sdk COMM_* code.

        Bytes already waiting before the instruction goes out are stale (the late reply to an
        earlier, timed-out transaction) and are discarded. A reply is accepted only if it answers
        this instruction: the right ID, the LENGTH this instruction's status packet has
        (``n_reply`` data bytes + 2) and a valid checksum; any other packet is skipped and the wait
        goes on until the reply timeout. A corrupt reply of the right ID and length ends the wait
        (COMM_RX_CORRUPT) so the caller can retry at once.
        """
        port = self.port
        if port is None or not self.port_ok:
            raise PortLostError(f'{self.config.device} is not open')
        key = (sid, instruction, tuple(params))
        pkt = self._packets.get(key)
        if pkt is None:
            pkt = p.encode_instruction(sid, instruction, params)
            if instruction == p.READ and len(self._packets) < 4096:
                self._packets[key] = pkt
        fd = port.ser.fd
        rx = self._rx
        try:
            if rx or in_waiting(fd):
                self.stale_bytes += len(rx) + self._discard_input(port)
                rx.clear()
            port.last_tx_time = self.clock()
            t0 = time.perf_counter()
            write_all(fd, pkt)
            if not expect_reply:
                return b'', COMM_SUCCESS, 0
            total = n_reply + 6
            deadline = t0 + (total * BITS_TIMES_1000 / self.baud_rate + 2.0 * port.latency_timer_ms
                             + port.margin_ms) * 1e-3
            while True:
                # parse what has arrived
                while len(rx) >= 4:
                    start = rx.find(p.HEADER)
                    if start < 0:
                        keep = 1 if rx[-1] == 0xFF else 0
                        self.stale_bytes += len(rx) - keep
                        del rx[:len(rx) - keep]
                        break
                    if start:
                        self.stale_bytes += start
                        del rx[:start]
                        continue
                    if rx[2] == 0xFF:
                        self.stale_bytes += 1
                        del rx[0]
                        continue
                    length = rx[3]
                    if length < 2:
                        self.stale_bytes += 2
                        del rx[:2]
                        continue
                    if len(rx) < length + 4:
                        break
                    ok = (~sum(rx[2:length + 3])) & 0xFF == rx[length + 3]
                    if rx[2] == sid and length == n_reply + 2:
                        if not ok:
                            rx.clear()
                            return b'', COMM_RX_CORRUPT, 0
                        err = rx[4]
                        data = bytes(rx[5:5 + n_reply])
                        del rx[:length + 4]
                        return data, COMM_SUCCESS, err
                    # a packet that does not answer this instruction (stale, foreign): skip it
                    self.stale_bytes += length + 4
                    del rx[:length + 4]
                left = deadline - time.perf_counter()
                if left <= 0:
                    return b'', COMM_RX_TIMEOUT, 0
                r, _, _ = select.select((fd,), (), (), left)
                if r:
                    chunk = os.read(fd, 4096)
                    if not chunk:
                        raise OSError('device reports readiness to read but returned no data '
                                      '(device disconnected?)')
                    rx += chunk
        except (serial.SerialException, OSError, ValueError, TypeError) as exc:
            rx.clear()
            self.port_ok = False
            raise PortLostError(f'{self.config.device}: {exc}') from None

    def _discard_input(self, port) -> int:
        """Throw away whatever the port has buffered; returns how many bytes."""
        n = 0
        fd = port.ser.fd
        while True:
            r, _, _ = select.select((fd,), (), (), 0)
            if not r:
                return n
            chunk = os.read(fd, 4096)
            if not chunk:
                raise OSError('device disconnected')
            n += len(chunk)

    def _sdk(self, fn, *args):
        """Call a dynamixel-sdk function; a vanished port raises PortLostError."""
        if self.port is None or not self.port_ok:
            raise PortLostError(f'{self.config.device} is not open')
        self.port.is_using = False
        try:
            return fn(self.port, *args)
        except (serial.SerialException, OSError) as exc:
            self.port.is_using = False
            self.port_ok = False
            raise PortLostError(f'{self.config.device}: {exc}') from None

    def _attempts(self, retries: int | None) -> int:
        if self._startup_attempts is not None:
            return self._startup_attempts
        return 1 + (self.config.read_retries if retries is None else retries)

    def _write(self, joint: str, address: int, data: list[int]) -> None:
        sid = self.mount[joint].servo_id
        last = ''
        attempts = self._attempts(None)
        for _ in range(attempts):
            _d, result, err = self._transact(sid, p.WRITE, [address, *data], 0)
            if result == COMM_SUCCESS and err & p.ERR_CHECKSUM:
                last = 'the servo received a corrupt instruction (checksum error)'
                continue
            if result == COMM_SUCCESS:
                if err & ~ALARM_BITS & ~p.ERR_INPUT_VOLTAGE:
                    raise BusError(f'{joint} (id {sid}): write of {data} at address {address} refused: '
                                   f'{p.describe_error(err)}')
                self.last_ok_t = self.clock()
                return
            last = _result_text(result)
        raise BusError(f'{joint} (id {sid}): write at address {address} failed after {attempts} attempts: {last}')

    def _read_raw(self, joint: str, address: int, n: int, retries: int | None = None):
        """Bytes read from a servo, or None after the retry budget (failures recorded).

        Each retry asks for one more byte than the attempt before (from an address moved down if
        the table ends), so the late reply to an earlier attempt has another LENGTH and can never
        be taken for the answer to this one."""
        sid = self.mount[joint].servo_id
        st = self.states[joint]
        for k in range(self._attempts(retries)):
            n_k = min(p.TABLE_SIZE, n + k)
            a_k = min(address, p.TABLE_SIZE - n_k)
            data, result, err = self._transact(sid, p.READ, [a_k, n_k], n_k)
            t_end = self.clock()
            if result == COMM_SUCCESS:
                self._last_read = (self.port.last_tx_time, t_end - self.port.last_tx_time, err)
                self.last_ok_t = t_end
                off = address - a_k
                return data[off:off + n]
            self.timing.failed()
            st.failed_attempts += 1
            st.message = 'no reply (timeout)' if result == COMM_RX_TIMEOUT else 'corrupt reply'
            self.last_failure = f'{joint} (id {sid}): read of {n} bytes at address {address}: {st.message}'
        return None

    def _read_joint(self, joint: str, retries: int) -> Sample | None:
        """Read one position; updates the servo state, applies the fault policy."""
        st = self.states[joint]
        data = self._read_raw(joint, 36, 2, retries)
        now = self.clock()
        if data is None:
            self._failure(joint, now)
            return None
        stamp, dur, err = self._last_read
        self.timing.read(dur)
        tick = _u16(data)
        st.present_tick = tick
        self._success(joint, err)
        return Sample(joint, self.to_theta(joint, tick), tick, stamp, dur, err)

    def _success(self, joint: str, err: int) -> None:
        st = self.states[joint]
        if st.missing or not st.responding:
            self._event('info', f'{joint} (id {st.servo_id}) answers again')
        st.responding, st.missing, st.consecutive_failures = True, False, 0
        if err != st.error_bits:
            if err:
                self._event('warn', f'{joint} (id {st.servo_id}) reports: {p.describe_error(err)}')
            elif st.error_bits:
                self._event('info', f'{joint} (id {st.servo_id}): error bits cleared')
        st.error_bits = err
        self._apply_fault_policy(joint, err)

    def _failure(self, joint: str, now: float) -> None:
        st = self.states[joint]
        st.consecutive_failures += 1
        st.responding = False
        if not st.missing and st.consecutive_failures < self.config.missing_after_failures:
            self._event('warn', f'{joint} (id {st.servo_id}): read failed after {1 + self.config.read_retries} '
                                f'attempts ({st.message}); no position reported', key=f'read-failed {joint}')
        if not st.missing and st.consecutive_failures >= self.config.missing_after_failures:
            st.missing = True
            self._event('error', f'{joint} (id {st.servo_id}) stopped answering ({st.message}); '
                                 f'skipped, re-probed every {self.config.reprobe_period_s} s')
        st.last_probe = now

    # ------------------------------------------------------------------ fault policy
    def _fault_message(self, st: ServoState) -> str:
        what = p.describe_error(st.faulted)
        limit = 'torque limit unknown' if st.torque_limit is None else f'torque limit {st.torque_limit}'
        state = 'limp' if st.torque_limit == 0 or not st.torque_enabled else 'torque on'
        if self.config.fault_policy == 'limp':
            return (f'{what}: alarm shutdown, {limit} ({state}); policy limp: torque '
                    f'{"off" if not st.torque_enabled else "enable still 1"}, commands ignored until restart')
        return (f'{what}: alarm shutdown, {limit} ({state}); policy recover: commands ignored, torque limit '
                f'restored once the alarm clears')

    def _apply_fault_policy(self, joint: str, err: int) -> None:
        """What the servo does on an alarm in alarm_shutdown: it zeroes its own torque limit
        (address 34) and goes limp, torque enable unchanged. The policy decides what follows:
        ``limp`` also writes torque enable 0 and leaves the joint out until restart; ``recover``
        sets the goal to the present position and writes the torque limit again once the alarm
        bit has cleared (the servo restores nothing by itself until power-up)."""
        st = self.states[joint]
        alarm = err & ALARM_BITS
        policy = self.config.fault_policy
        if alarm and not st.faulted:
            st.faulted = alarm
            data = self._read_raw(joint, 34, 2, retries=self.config.read_retries)
            st.torque_limit = _u16(data) if data is not None else None
            if policy == 'limp' and self._write_quiet(joint, 24, [0]):
                st.torque_enabled = False
            st.message = self._fault_message(st)
            self._event('error', f'{joint} (id {st.servo_id}) {st.message}')
        elif st.faulted and not alarm and policy == 'recover':
            tick = st.present_tick if st.present_tick is not None else self.goals_tick.get(joint)
            if tick is not None:
                self._write_quiet(joint, 30, _word(tick))
                self.goals_tick[joint] = tick
            if self._write_quiet(joint, 34, _word(self.config.torque_limit)):
                data = self._read_raw(joint, 34, 2, retries=self.config.read_retries)
                st.torque_limit = _u16(data) if data is not None else None
                if st.torque_limit == self.config.torque_limit:
                    st.faulted = 0
                    st.message = f'recovered: alarm cleared, torque limit {st.torque_limit} restored (read back)'
                    self._event('info', f'{joint} (id {st.servo_id}) {st.message}')

    def _write_quiet(self, joint: str, address: int, data: list[int]) -> bool:
        try:
            self._write(joint, address, data)
            return True
        except PortLostError:
            raise
        except BusError as exc:
            self._event('error', str(exc))
            return False

    # ------------------------------------------------------------------ commands
    @dataclass(frozen=True)
    class Validated:
        goals_tick: dict[str, int]
        warnings: list[str]

    def _check_joint(self, joint: str) -> None:
        if joint not in self.mount:
            try:
                parse_joint_name(joint)
            except DescriptionError as exc:
                raise CommandError(f'unknown joint {joint!r}: {exc}') from None
            raise CommandError(f'unknown joint {joint!r}')

    def validate_goals(self, goals_rad: Mapping[str, float]) -> 'DynamixelBus.Validated':
        """Goals -> raw ticks. Unknown names and non-finite values reject the whole command; values
        outside the joint limits are clamped (with a warning) or rejected, per ``limit_policy``."""
        if not goals_rad:
            raise CommandError('empty command: no joint goals')
        out, warnings = {}, []
        for joint, theta in goals_rad.items():
            self._check_joint(joint)
            try:
                theta = float(theta)
            except (TypeError, ValueError):
                raise CommandError(f'{joint}: goal {theta!r} is not a number') from None
            if not math.isfinite(theta):
                raise CommandError(f'{joint}: goal {theta} is not finite; command rejected')
            lo, hi = self.robot.joint_limits(joint)
            if not lo <= theta <= hi:
                if self.config.limit_policy == 'reject':
                    raise CommandError(f'{joint}: goal {theta:.4f} rad outside the joint limits [{lo}, {hi}]; '
                                       f'command rejected')
                clamped = min(hi, max(lo, theta))
                warnings.append(f'{joint}: goal {theta:.4f} rad outside [{lo}, {hi}], clamped to {clamped}')
                theta = clamped
            out[joint] = self.to_tick(joint, theta)
        return DynamixelBus.Validated(out, warnings)

    def set_command(self, names: Sequence[str], positions: Sequence[float], stamp: float | None = None) -> list[str]:
        """Queue goals (from /joint_commands) for the next step; returns warnings.

        Raises :class:`CommandError` (nothing queued) for a malformed, stale or rejected command.
        """
        if len(names) != len(positions):
            raise CommandError(f'{len(names)} joint names but {len(positions)} positions')
        if len(set(names)) != len(names):
            raise CommandError(f'duplicate joint names in command: {list(names)}')
        if self.estopped:
            raise CommandError('emergency stop is active: torque is off; restart the driver to re-enable')
        now = self.clock()
        timeout = self.config.command_timeout_s
        if stamp and timeout > 0 and now - stamp > timeout:
            raise CommandError(f'stale command: stamped {now - stamp:.3f} s ago (command_timeout_s={timeout})')
        v = self.validate_goals(dict(zip(names, positions)))
        warnings = list(v.warnings)
        goals = {}
        for j, tick in v.goals_tick.items():
            st = self.states[j]
            if st.faulted:
                warnings.append(f'{j}: ignored, servo in fault ({st.message})')
                continue
            goals[j] = tick
        with self._cmd_lock:
            self._pending.update(goals)
            self._last_command_t = now
        self._cmd_event.set()
        return warnings

    def set_schedule(self, names: Iterable[str]) -> tuple[str, ...]:
        """Set the read order (empty = all 18 joints). Unknown names reject the whole schedule."""
        names = tuple(names)
        for n in names:
            self._check_joint(n)
        with self._cmd_lock:
            self._schedule = names or self.joints
            self._cursor = 0
        return self._schedule

    @property
    def schedule(self) -> tuple[str, ...]:
        return self._schedule

    def _sync_write_ticks(self, goals: Mapping[str, int]) -> float:
        goals = {j: t for j, t in goals.items() if not self.states[j].faulted}
        if not goals:
            return self.clock()
        params = []
        for j, tick in goals.items():
            params += [self.mount[j].servo_id, tick & 0xFF, tick >> 8]
        t0 = self.clock()
        self._transact(p.BROADCAST_ID, p.SYNC_WRITE, [30, 2, *params], 0, expect_reply=False)
        t = self.port.last_tx_time
        self.timing.write(self.clock() - t0)
        self.goals_tick.update(goals)
        return t

    # ------------------------------------------------------------------ emergency stop / shutdown
    def torque_off(self) -> list[str]:
        """Torque off on every servo: a broadcast write, then each servo read back (and written
        individually if needed). Returns joints whose torque could not be confirmed off; raises
        PortLostError when the port is gone."""
        unconfirmed = []
        with self.lock:
            if not self.port_ok:
                raise PortLostError(f'{self.config.device} is not open')
            self._transact(p.BROADCAST_ID, p.WRITE, [24, 0], 0, expect_reply=False)
            for j in self.joints:
                data = self._read_raw(j, 24, 1, retries=self.config.read_retries)
                if data is not None and data[0] == 0:
                    self.states[j].torque_enabled = False
                    continue
                try:
                    self._write(j, 24, [0])
                    self.states[j].torque_enabled = False
                except BusError:
                    unconfirmed.append(j)
        return unconfirmed

    def torque_off_report(self) -> tuple[bool, str]:
        """Torque off everywhere; (confirmed, what the driver knows), never claiming more than it
        saw: "torque off" only when every servo answered the write or read back 0."""
        with self.lock:
            if (self.port is None or not self.port_ok) and not self._reopen_for_torque_off():
                return False, 'torque state unknown: port lost (nothing could reach the servos)'
            try:
                bad = self.torque_off()
            except PortLostError as exc:
                self.port_ok = False
                if not self._reopen_for_torque_off():
                    return False, f'torque state unknown: port lost ({exc})'
                try:
                    bad = self.torque_off()
                except PortLostError as exc2:
                    return False, f'torque state unknown: port lost ({exc2})'
        if bad:
            return False, (f'torque state unknown for {", ".join(bad)} (no answer); '
                           f'torque off confirmed for the other {len(self.joints) - len(bad)}')
        return True, 'torque off on all servos (read back)'

    def emergency_stop(self) -> tuple[bool, str]:
        """Torque off everywhere and refuse further commands."""
        self.estopped = True
        with self._cmd_lock:
            self._pending.clear()
        ok, text = self.torque_off_report()
        if ok:
            return True, f'emergency stop: {text}; commands are refused until the driver restarts'
        return False, f'emergency stop: {text}; commands are refused until the driver restarts'

    def shutdown(self) -> tuple[bool, str]:
        """Torque off and close the port (safe to call twice): (confirmed, what the driver knows)."""
        with self.lock:
            if self.port is None and self._closed_report is not None:
                return self._closed_report
            ok, text = self.torque_off_report()
            self._close_port()
            self._closed_report = (ok, text)
        return ok, text

    def close(self) -> list[str]:
        """Torque off and close the port (safe to call twice). Returns joints whose torque is not
        confirmed off (all of them when the port was lost)."""
        with self.lock:
            if self.port is None and self._closed_report is not None and self._closed_report[0]:
                return []
            if self.port is None or not self.port_ok:
                self._close_port()
                return list(self.joints)
            try:
                bad = self.torque_off()
            except PortLostError:
                bad = list(self.joints)
            self._close_port()
            self._closed_report = (not bad, '')
        return bad

    # ------------------------------------------------------------------ the bus loop
    def step(self) -> StepResult:
        """One iteration of the bus loop: reconnect if needed, write pending goals, hold on stale
        commands, read the next scheduled joint, one diagnostics read when a round is due."""
        res = StepResult()
        # read pacing: wait for the next read slot, but write goals the moment they arrive
        while self.config.read_period_s > 0 and self.port_ok:
            now = self.clock()
            self._watch_clock(now)
            left = self._next_read_t - now
            if left <= 0:
                break
            if self._cmd_event.wait(min(left, 0.05)):
                self._cmd_event.clear()
                with self.lock:
                    self._guarded(lambda: self._write_pending(res))
            if self._clock_paused:           # back to the caller now and then: it may be stopping
                res.events = self._drain_events()
                return res
        now = self.clock()
        self._watch_clock(now)
        with self.lock:
            if not self.port_ok:
                if now >= self._next_reconnect_t:
                    self._next_reconnect_t = now + self.config.reconnect_period_s
                    self._reconnect()
                if not self.port_ok:
                    res.events = self._drain_events()
                    self._sleep(0.005)
                    return res
            self._guarded(lambda: (self._write_pending(res), self._check_stale(now), self._read_next(res, now),
                                   self._diagnostics_step(res, now)))
        res.events = self._drain_events()
        return res

    def _watch_clock(self, now: float) -> None:
        """Notice a clock that jumps back (sim time reset, a system clock set back) and one that stands
        still (use_sim_time with a paused /clock): one line each. After a jump back, the times the
        loop waits for (next read, diagnostics round, reopen, the watchdog's last transaction, the
        command timeout) restart from the new time instead of waiting for the clock to catch up."""
        wall = time.monotonic()
        seen = self._clock_seen
        if seen is not None and now < seen[0] - CLOCK_JUMP_S:
            self._event('warn', f'clock jumped back by {seen[0] - now:.3f} s (to {now:.3f} s): read pacing, '
                                f'diagnostics, reopen and command timeouts restart from the new time')
            self._next_read_t = min(self._next_read_t, now)
            self._next_diag_t = min(self._next_diag_t, now)
            self._next_reconnect_t = min(self._next_reconnect_t, now)
            self.last_ok_t = min(self.last_ok_t, now)
            if self._last_command_t is not None:
                self._last_command_t = min(self._last_command_t, now)
        if seen is None or now != seen[0]:
            if self._clock_paused:
                self._clock_paused = False
                self._event('info', f'the clock advances again (at {now:.3f} s)')
            self._clock_seen = (now, wall)
        elif not self._clock_paused and wall - seen[1] >= CLOCK_PAUSE_S:
            self._clock_paused = True
            self._event('warn', f'the clock is not advancing (at {now:.3f} s for {wall - seen[1]:.1f} s of wall '
                                f'time: use_sim_time with a paused /clock?): reads wait for it')

    def _guarded(self, fn) -> None:
        """Run bus work; a lost port or a failed transaction becomes an event, never an exception."""
        try:
            fn()
        except PortLostError as exc:
            self._port_lost(exc)
        except BusError as exc:
            self._event('error', str(exc))

    def _port_lost(self, exc: Exception) -> None:
        """The port failed (in the bus loop or under a controller's read or write): one error event
        per loss, every servo not responding, the next reopen one ``reconnect_period_s`` away."""
        self.port_ok = False
        for st in self.states.values():
            st.responding = False
        if self._loss_reported:
            return
        self._loss_reported = True
        self._event('error', f'port lost: {exc}; torque state unknown (nothing reaches the servos); '
                             f'reopening every {self.config.reconnect_period_s} s')
        self._next_reconnect_t = self.clock() + self.config.reconnect_period_s

    def _reopen_for_torque_off(self) -> bool:
        """The port is lost when torque is to be turned off (at exit, an emergency stop): try to
        reopen it for :data:`TORQUE_OFF_REOPEN_S` (an adapter plugged back in), on the monotonic
        clock (a paused ROS clock must not hold an exit). True when it is open again."""
        t_end = time.monotonic() + TORQUE_OFF_REOPEN_S
        while True:
            try:
                self._open()
                return True
            except PortLostError:
                if time.monotonic() >= t_end:
                    return False
                time.sleep(0.05)

    def _reconnect(self) -> None:
        try:
            self._open()
            with self._startup_timeouts():
                self.verify()
                self.configure(enable_torque=not self.estopped)   # goals = present positions: no jump
            with self._cmd_lock:
                self._pending.clear()
            self._event_end('reconnect')
            self._event('info', f'{self.config.device} reopened, servos verified and holding position')
        except BusError as exc:
            self._close_port()
            self._event('error', f'reconnect failed: {exc}', key='reconnect')

    def _write_pending(self, res: StepResult) -> None:
        with self._cmd_lock:
            goals, self._pending = self._pending, {}
            if goals:
                self._holding = False
        if goals and not self.estopped:
            self._sync_write_ticks(goals)
            res.wrote = True

    def _check_stale(self, now: float) -> None:
        timeout = self.config.command_timeout_s
        last = self._last_command_t
        if timeout <= 0 or last is None or self._holding or now - last <= timeout or self.estopped:
            return
        self._holding = True
        hold = {}
        for j in self.joints:
            st = self.states[j]
            if st.missing or st.faulted:
                continue
            data = self._read_raw(j, 36, 2, retries=0)
            if data is not None:
                hold[j] = _u16(data)
        if hold:
            self._sync_write_ticks(hold)
        self._event('warn', f'no command for {now - last:.2f} s (command_timeout_s={timeout}): holding '
                            f'{len(hold)} joints at their present positions')

    def _read_next(self, res: StepResult, now: float) -> None:
        with self._cmd_lock:
            sched, start = self._schedule, self._cursor
            self._cursor = (start + 1) % len(sched)
        for k in range(len(sched)):
            joint = sched[(start + k) % len(sched)]
            st = self.states[joint]
            if st.missing and now - st.last_probe < self.config.reprobe_period_s:
                continue
            if k:
                with self._cmd_lock:
                    if self._schedule is sched:
                        self._cursor = (start + k + 1) % len(sched)
            s = self._read_joint(joint, retries=0 if st.missing else self.config.read_retries)
            if s is not None:
                res.samples.append(s)
                self._next_read_t = s.stamp + self.config.read_period_s
            return
        self._sleep(0.001)               # every scheduled servo is missing: do not spin

    def _diagnostics_step(self, res: StepResult, now: float) -> None:
        if not self._diag_queue:
            if now < self._next_diag_t:
                return
            self._next_diag_t = now + self.config.diagnostics_period_s
            self._diag_queue = list(self.joints)
        joint = self._diag_queue.pop(0)
        st = self.states[joint]
        if not st.missing or now - st.last_probe >= self.config.reprobe_period_s:
            data = self._read_raw(joint, DIAG_START, DIAG_LEN, retries=0 if st.missing else self.config.read_retries)
            if data is None:
                self._failure(joint, self.clock())
            else:
                _stamp, _dur, err = self._last_read
                d = {a: data[a - DIAG_START] for a in range(DIAG_START, DIAG_START + DIAG_LEN)}
                st.torque_enabled = bool(d[24])
                st.torque_limit = d[34] | d[35] << 8
                st.present_tick = d[36] | d[37] << 8
                st.load_fraction = p.decode_load(d[40] | d[41] << 8)
                st.voltage_v = d[42] * p.VOLTAGE_UNIT_V
                st.temperature_c = float(d[43])
                self._success(joint, err)
                if st.faulted:
                    st.message = self._fault_message(st)
                else:
                    st.message = (p.describe_error(err) if err else
                                  'ok' if st.torque_enabled and st.torque_limit else
                                  'torque off' if not st.torque_enabled else 'torque limit 0 (limp)')
                if st.failed_attempts:
                    st.message += f'; {st.failed_attempts} read attempts without a valid reply since start-up'
        if not self._diag_queue:
            res.diagnostics = [replace(self.states[j]) for j in self.joints]

    # ------------------------------------------------------------------ events
    def _event(self, level: str, text: str, key: str | None = None) -> None:
        """Queue a log event. With a ``key``, repeats within ``throttle_s`` are counted instead of
        queued, and summarised when the window ends or :meth:`_event_end` closes the series."""
        if key is not None:
            now = self.clock()
            th = self._throttle.get(key)
            if th is not None and now - th[0] < self.throttle_s:
                th[1] += 1
                th[3] = text
                return
            if th is not None and th[1]:
                text = f'{text} (and {th[1]} more times in the last {self.throttle_s:g} s)'
            self._throttle[key] = [now, 0, level, text]
        self._events.append((level, text))

    def _event_end(self, key: str) -> None:
        th = self._throttle.pop(key, None)
        if th is not None and th[1]:
            self._events.append((th[2], f'{th[3]} (repeated {th[1]} more times before it stopped)'))

    def _drain_events(self) -> list[tuple[str, str]]:
        ev = list(self._events)
        self._events.clear()
        return ev

    def take_events(self) -> list[tuple[str, str]]:
        """Events (level, text) not yet returned by :meth:`step` (for direct library use)."""
        with self.lock:
            return self._drain_events()


BITS_TIMES_1000 = p.BITS_PER_BYTE * 1000.0


def _result_text(result: int) -> str:
    return {COMM_RX_TIMEOUT: 'no reply (timeout)', COMM_RX_CORRUPT: 'corrupt reply'}.get(result, f'result {result}')


def _word(v: int) -> list[int]:
    return [int(v) & 0xFF, (int(v) >> 8) & 0xFF]


def _u16(data: bytes) -> int:
    return data[0] | data[1] << 8
