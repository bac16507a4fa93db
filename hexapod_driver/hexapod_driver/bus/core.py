""":class:`DynamixelBus`: one AX-12A bus, without any ROS import, built from its layers.

* :class:`~hexapod_driver.bus.transport.Transport`: the port and the framing;
* :class:`~hexapod_driver.bus.servo_setup.ServoSetup`: verification and configuration;
* :class:`~hexapod_driver.bus.policy.ServoPolicy`: what each answer or silence means (retries,
  missing servos, faults), :class:`~hexapod_driver.bus.commands.Commands` (goals, schedule) and
  :class:`~hexapod_driver.bus.loop.BusLoop` (the loop the node runs, :meth:`DynamixelBus.step`).

The bus implements the :class:`hexapod_model.bus.ServoBus` protocol (``now``, ``sync_write``,
``read_position``, ``wait_until``), so the locomotion library can run on it directly. One lock
(:attr:`DynamixelBus.lock`) is taken by every bus transaction. Its life: :meth:`open` (port
opened, servos verified and configured, torque off), :meth:`enable_torque`, :meth:`torque_off`,
:meth:`close`; :meth:`start` is the first two at once.
"""
from __future__ import annotations

import contextlib
import math
import threading
import time
from typing import Callable, Iterable, Mapping, Sequence

from hexapod_driver import protocol as p
from hexapod_driver.bus.commands import ESTOP_TEXT, CommandError, Commands, Validated
from hexapod_driver.bus.events import Event, EventLog
from hexapod_driver.bus.loop import BusLoop, StepResult
from hexapod_driver.bus.policy import ServoPolicy
from hexapod_driver.bus.servo_setup import ServoSetup
from hexapod_driver.bus.state import ServoState
from hexapod_driver.bus.transport import PortLostError, ReadResult, Transport
from hexapod_driver.config import DriverConfig
from hexapod_driver.timing import TimingStats
from hexapod_model.bus import BusError, Scheduled, ServoBus
from hexapod_model.description import ALL_JOINTS, BusJoint, Robot
from hexapod_model.servo import servo_theta, servo_tick

TORQUE_OFF_REOPEN_S = 1.0             # how long a torque-off (exit, emergency stop) tries to reopen a lost port


class DynamixelBus(ServoBus, Scheduled):
    """The AX-12A bus. Thread-safe: every transaction holds :attr:`lock`. ``transport`` replaces
    the serial port's (a test's, to inject what a port can do)."""

    def __init__(self, robot: Robot, config: DriverConfig = DriverConfig(), *,
                 clock: Callable[[], float] = time.time, sleep: Callable[[float], None] = time.sleep,
                 t_com_s: float | None = None, transport: Transport | None = None):
        config.validate()
        self.robot = robot
        self.config = config
        self.clock = clock
        self.sleep = sleep
        self.t_com_s = robot.bus.t_com_s if t_com_s is None else float(t_com_s)
        self.baud_rate = int(robot.bus.baud_rate)
        self.mount: dict[str, BusJoint] = {j.joint: j for j in robot.bus.joints}   # the description's mounting
        self.joints = tuple(ALL_JOINTS)
        self.margin = robot.servo.compliance_margin_ticks    # the model's servo law assumes these
        self.slope = robot.servo.compliance_slope_ticks
        self.punch = robot.servo.punch
        self.moving_speed = robot.servo.moving_speed
        self.lock = threading.RLock()
        self.transport = transport or Transport(config.device, self.baud_rate, config.latency_timer_ms,
                                                config.timeout_margin_ms, clock)
        self.states = {j: ServoState(j, self.mount[j].servo_id) for j in self.joints}
        self.goals_tick: dict[str, int] = {}
        self.timing = TimingStats()
        self.estopped = False
        self.last_failure = ''
        self.reply_latency_s = math.nan            # measured at start-up (fastest PING round trip - wire)
        self.events = EventLog(clock)
        self.commands = Commands(robot, self.joints, self.to_tick, config.limit_policy, config.command_timeout_s,
                                 clock)
        self.setup = ServoSetup(self)
        self.policy = ServoPolicy(self)
        self.loop = BusLoop(self)
        self._startup_attempts: int | None = None  # attempts per transaction while starting up
        self._closed_report: tuple[bool, str] | None = None

    # ------------------------------------------------------------------ state of the layers
    @property
    def port_ok(self) -> bool:
        return self.transport.port_ok

    @property
    def port(self):
        return self.transport.port

    @property
    def last_ok_t(self) -> float:
        """clock() of the last answered transaction (the node's watchdog)."""
        return self.transport.last_ok_t

    @property
    def throttle_s(self) -> float:
        return self.events.throttle_s

    @throttle_s.setter
    def throttle_s(self, value: float) -> None:
        self.events.throttle_s = value

    @property
    def next_read_t(self) -> float:
        """When :meth:`step` may read next (read pacing, ``read_period_s``); -inf without pacing."""
        return self.loop.next_read_t if self.config.read_period_s > 0 else -math.inf

    @property
    def schedule(self) -> tuple[str, ...]:
        return self.commands.schedule

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

    # ------------------------------------------------------------------ registers (with the retry policy)
    def attempts(self, retries: int | None = None) -> int:
        """Tries per transaction: ``startup_attempts`` while starting up, else 1 + ``retries``
        (default ``read_retries``)."""
        if self._startup_attempts is not None:
            return self._startup_attempts
        return 1 + (self.config.read_retries if retries is None else retries)

    def read_register(self, joint: str, address: int, n: int, retries: int | None = None) -> ReadResult:
        """Read a servo's registers; every failed attempt is counted (timing, the servo's state)."""
        st = self.states[joint]
        r = self.transport.read(st.servo_id, address, n, self.attempts(retries))
        for _ in r.failures:
            self.timing.failed()
        if r.failures:
            st.failed_attempts += len(r.failures)
            st.message = r.failures[-1]
            self.last_failure = f'{joint} (id {st.servo_id}): read of {n} bytes at address {address}: {st.message}'
        return r

    def write_register(self, joint: str, address: int, data: list[int]) -> None:
        sid = self.mount[joint].servo_id
        self.transport.write(sid, address, data, self.attempts(), f'{joint} (id {sid})')

    def write_goals(self, goals: Mapping[str, int]) -> float:
        """One SYNC_WRITE of goal positions [ticks] (joints in fault left out); returns its time."""
        goals = {j: t for j, t in goals.items() if not self.states[j].faulted}
        if not goals:
            return self.clock()
        params = []
        for j, tick in goals.items():
            params += [self.mount[j].servo_id, *p.word(tick)]
        t0 = self.clock()
        t = self.transport.send(p.BROADCAST_ID, p.SYNC_WRITE, [30, 2, *params])
        self.timing.write(self.clock() - t0)
        self.goals_tick.update(goals)
        return t

    # ------------------------------------------------------------------ ServoBus protocol
    def now(self) -> float:
        return self.clock()

    def wait_until(self, t: float) -> None:
        while True:
            left = t - self.clock()
            if left <= 0:
                return
            self.sleep(min(left, 0.05))

    def sync_write(self, goals_rad: Mapping[str, float]) -> float:
        """Validate and write goals at once (one SYNC_WRITE); returns the write time."""
        if self.estopped:
            raise CommandError(ESTOP_TEXT)
        goals = self.validate_goals(goals_rad).goals_tick
        with self.lock:
            try:
                return self.write_goals(goals)
            except PortLostError as exc:
                self.loop.port_lost(exc)
                raise

    def read_position(self, joint: str) -> tuple[float, float]:
        """Read one joint: (theta [rad], sample time). Raises BusError after the retry budget."""
        self.commands.check_joint(joint)
        with self.lock:
            try:
                s = self.policy.read_joint(joint, retries=self.config.read_retries)
            except PortLostError as exc:
                self.loop.port_lost(exc)
                raise
        if s is None:
            raise BusError(f'{joint} (id {self.mount[joint].servo_id}): no valid reply after '
                           f'{1 + self.config.read_retries} attempts ({self.states[joint].message})')
        return s.theta_rad, s.stamp

    # ------------------------------------------------------------------ commands and schedule
    def validate_goals(self, goals_rad: Mapping[str, float]) -> Validated:
        return self.commands.validate_goals(goals_rad)

    def set_command(self, names: Sequence[str], positions: Sequence[float], stamp: float | None = None) -> list[str]:
        """Queue goals (from /joint_commands) for the next step; returns warnings.

        Raises :class:`CommandError` (nothing queued) for a malformed, stale or rejected command."""
        if self.estopped:
            raise CommandError(ESTOP_TEXT)
        faulted = {j: st.message for j, st in self.states.items() if st.faulted}
        return self.commands.set_command(names, positions, stamp, faulted)

    def set_schedule(self, names: Iterable[str]) -> tuple[str, ...]:
        """Set the read order (empty = all 18 joints). Unknown names reject the whole schedule."""
        return self.commands.set_schedule(names)

    # ------------------------------------------------------------------ life: open, torque, close
    def start(self) -> None:
        """Open the port, verify all servos, configure them and enable torque."""
        self.open(enable_torque=True)

    def open(self, enable_torque: bool = False) -> None:
        """Open the port, verify all servos and configure them; torque enable as asked."""
        with self.lock:
            self.open_and_configure(enable_torque)
            self._closed_report = None

    def open_and_configure(self, enable_torque: bool) -> None:
        """(Re)open the port, verify and configure with start-up's timeouts and attempts (lock held)."""
        self.transport.open()
        self.loop.loss_reported = False
        with self._starting_up():
            self.setup.verify()
            self.setup.configure(enable_torque)

    @contextlib.contextmanager
    def _starting_up(self):
        """Start-up's longer reply timeout and ``startup_attempts`` tries per transaction."""
        with self.transport.reply_margin(self.config.startup_timeout_margin_ms):
            self._startup_attempts = self.config.startup_attempts
            try:
                yield
            finally:
                self._startup_attempts = None

    def enable_torque(self) -> None:
        """Goals to the present positions, then torque on (clears an emergency stop); as a part of
        start-up, with its timeouts and attempts."""
        with self.lock:
            if not self.port_ok:
                raise PortLostError(f'{self.config.device} is not open')
            with self._starting_up():
                self.setup.hold(enable_torque=True)
            self.estopped = False
            self.commands.clear()

    def torque_off(self) -> list[str]:
        """Torque off on every servo: a broadcast write, then each servo read back (and written
        individually if needed). Returns joints whose torque could not be confirmed off; raises
        PortLostError when the port is gone."""
        unconfirmed = []
        with self.lock:
            if not self.port_ok:
                raise PortLostError(f'{self.config.device} is not open')
            self.transport.send(p.BROADCAST_ID, p.WRITE, [24, 0])
            for j in self.joints:
                data = self.read_register(j, 24, 1, retries=self.config.read_retries).data
                if data is not None and data[0] == 0:
                    self.states[j].torque_enabled = False
                    continue
                try:
                    self.write_register(j, 24, [0])
                    self.states[j].torque_enabled = False
                except BusError:
                    unconfirmed.append(j)
        return unconfirmed

    def torque_off_report(self) -> tuple[bool, str]:
        """Torque off everywhere; (confirmed, what the driver knows), never claiming more than it
        saw: "torque off" only when every servo answered the write or read back 0."""
        with self.lock:
            if not self.port_ok and not self._reopen_for_torque_off():
                return False, 'torque state unknown: port lost (nothing could reach the servos)'
            try:
                bad = self.torque_off()
            except PortLostError as exc:
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

    def _reopen_for_torque_off(self) -> bool:
        """The port is lost when torque is to be turned off (at exit, an emergency stop): try to
        reopen it for :data:`TORQUE_OFF_REOPEN_S` (an adapter plugged back in), on the monotonic
        clock (a paused ROS clock must not hold an exit). True when it is open again."""
        t_end = time.monotonic() + TORQUE_OFF_REOPEN_S
        while True:
            try:
                self.transport.open()
                return True
            except PortLostError:
                if time.monotonic() >= t_end:
                    return False
                time.sleep(0.05)

    def emergency_stop(self) -> tuple[bool, str]:
        """Torque off everywhere and refuse further commands."""
        self.estopped = True
        self.commands.clear()
        ok, text = self.torque_off_report()
        return ok, f'emergency stop: {text}; commands are refused until the driver restarts (or is deactivated and activated again)'

    def shutdown(self) -> tuple[bool, str]:
        """Torque off and close the port (safe to call twice): (confirmed, what the driver knows)."""
        with self.lock:
            if self.port is None and self._closed_report is not None:
                return self._closed_report
            ok, text = self.torque_off_report()
            self.transport.close()
            self._closed_report = (ok, text)
        return ok, text

    def close(self) -> list[str]:
        """Torque off and close the port (safe to call twice). Returns joints whose torque is not
        confirmed off (all of them when the port was lost)."""
        with self.lock:
            if self.port is None and self._closed_report is not None and self._closed_report[0]:
                return []
            if not self.port_ok:
                self.transport.close()
                return list(self.joints)
            try:
                bad = self.torque_off()
            except PortLostError:
                bad = list(self.joints)
            self.transport.close()
            self._closed_report = (not bad, '')
        return bad

    # ------------------------------------------------------------------ the bus loop
    def step(self) -> StepResult:
        """One iteration of the bus loop (:class:`~hexapod_driver.bus.loop.BusLoop`)."""
        return self.loop.step()

    def take_events(self) -> list[Event]:
        """Events not yet returned by :meth:`step` (for direct library use)."""
        with self.lock:
            return self.events.drain()
