"""Policy: what the driver makes of each answer or silence of a servo.

:class:`ServoPolicy` keeps :class:`ServoState` up to date from every read: a failed read (after
its retries) is reported, a servo failing ``missing_after_failures`` times in a row is skipped and
only re-probed every ``reprobe_period_s``, one that answers again is welcomed back; changed error
bits are reported; an alarm (overheating, overload) triggers the fault policy, ``limp`` or
``recover``. A diagnostics read (registers 24..46 in one READ) fills in temperature, voltage,
load, torque enable and limit. A position is only ever reported when a servo returned it.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

from hexapod_driver import protocol as p
from hexapod_driver.bus.events import EventKind
from hexapod_driver.bus.host import BusHost
from hexapod_driver.bus.state import Sample
from hexapod_driver.bus.transport import ALARM_BITS, PortLostError
from hexapod_driver.protocol import u16, word
from hexapod_driver.timing import TimingStats
from hexapod_model.bus import BusError

DIAG_START = 24                       # torque_enable .. moving in one READ
DIAG_LEN = 46 - DIAG_START + 1


@runtime_checkable
class PolicyHost(BusHost, Protocol):
    """What :class:`ServoPolicy` uses of its bus (:class:`~hexapod_driver.bus.core.DynamixelBus`)."""

    goals_tick: dict[str, int]
    timing: TimingStats

    def to_theta(self, joint: str, tick: float) -> float: ...


class ServoPolicy:
    """Reads through the policy, for one :class:`DynamixelBus` (its lock held)."""

    def __init__(self, bus: PolicyHost):
        self.bus = bus
        self.config = bus.config
        self.states = bus.states
        self.events = bus.events

    def due(self, joint: str, now: float) -> bool:
        """A missing servo is only tried again every ``reprobe_period_s``."""
        st = self.states[joint]
        return not st.missing or now - st.last_probe >= self.config.reprobe_period_s

    def retries(self, joint: str) -> int:
        return 0 if self.states[joint].missing else self.config.read_retries

    def read_joint(self, joint: str, retries: int) -> Sample | None:
        """Read one position; updates the servo state, applies the fault policy."""
        bus = self.bus
        r = bus.read_register(joint, 36, 2, retries)
        if r.data is None:
            self.failure(joint, bus.clock())
            return None
        bus.timing.read(r.t_com_s)
        tick = u16(r.data)
        self.states[joint].present_tick = tick
        self.success(joint, r.error_bits)
        return Sample(joint, bus.to_theta(joint, tick), tick, r.stamp, r.t_com_s, r.error_bits)

    def _read_block(self, joint: str, retries: int):
        """Registers 24..46 in one READ into the servo's state (torque enable and limit, position,
        load, voltage, temperature); the read's result."""
        st = self.states[joint]
        r = self.bus.read_register(joint, DIAG_START, DIAG_LEN, retries)
        if r.data is not None:
            def value(name: str) -> int:
                return p.register_value(r.data, DIAG_START, name)
            st.torque_enabled = bool(value('torque_enable'))
            st.torque_limit = value('torque_limit')
            st.present_tick = value('present_position')
            st.load_fraction = p.decode_load(value('present_load'))
            st.voltage_v = value('present_voltage') * p.VOLTAGE_UNIT_V
            st.temperature_c = float(value('present_temperature'))
        return r

    def read_diagnostics(self, joint: str) -> None:
        """One diagnostics read of ``joint`` (registers 24..46)."""
        st = self.states[joint]
        r = self._read_block(joint, self.retries(joint))
        if r.data is None:
            self.failure(joint, self.bus.clock())
            return
        err = r.error_bits
        self.success(joint, err)
        if st.faulted:
            st.message = self.fault_message(st)
        else:
            st.message = (p.describe_error(err) if err else
                          'ok' if st.torque_enabled and st.torque_limit else
                          'torque off' if not st.torque_enabled else 'torque limit 0 (limp)')
        if st.failed_attempts:
            st.message += f'; {st.failed_attempts} read attempts without a valid reply since start-up'

    def success(self, joint: str, err: int) -> None:
        st = self.states[joint]
        who = dict(joint=joint, servo_id=st.servo_id)
        if st.missing or not st.responding:
            self.events.emit(EventKind.SERVO_ANSWERS, **who)
        st.responding, st.missing, st.consecutive_failures = True, False, 0
        if err != st.error_bits:
            if err:
                self.events.emit(EventKind.ERROR_BITS, **who, error_bits=err, errors=p.describe_error(err))
            elif st.error_bits:
                self.events.emit(EventKind.ERROR_BITS_CLEARED, **who)
        st.error_bits = err
        self.apply_fault_policy(joint, err)

    def failure(self, joint: str, now: float) -> None:
        st = self.states[joint]
        st.consecutive_failures += 1
        st.responding = False
        who = dict(joint=joint, servo_id=st.servo_id, reason=st.message)
        if not st.missing and st.consecutive_failures < self.config.missing_after_failures:
            self.events.emit(EventKind.READ_FAILED, key=f'read-failed {joint}', **who,
                             attempts=1 + self.config.read_retries)
        if not st.missing and st.consecutive_failures >= self.config.missing_after_failures:
            st.missing = True
            self.events.emit(EventKind.SERVO_MISSING, **who, period_s=self.config.reprobe_period_s)
        st.last_probe = now

    # ------------------------------------------------------------------ fault policy
    def fault_message(self, st) -> str:
        what = p.describe_error(st.faulted)
        limit = 'torque limit unknown' if st.torque_limit is None else f'torque limit {st.torque_limit}'
        state = 'limp' if st.torque_limit == 0 or not st.torque_enabled else 'torque on'
        if self.config.fault_policy == 'limp':
            return (f'{what}: alarm shutdown, {limit} ({state}); policy limp: torque '
                    f'{"off" if not st.torque_enabled else "enable still 1"}, commands ignored until restart')
        return (f'{what}: alarm shutdown, {limit} ({state}); policy recover: commands ignored, torque limit '
                f'restored once the alarm clears')

    def apply_fault_policy(self, joint: str, err: int) -> None:
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
            # the whole block, so the fault is reported with the temperature and torque limit it has now
            if self._read_block(joint, self.config.read_retries).data is None:
                st.torque_limit = None
            if policy == 'limp' and self.write_quiet(joint, 24, [0]):
                st.torque_enabled = False
            st.message = self.fault_message(st)
            self.events.emit(EventKind.FAULT, joint=joint, servo_id=st.servo_id, alarm_bits=alarm, policy=policy,
                             torque_limit=st.torque_limit, torque_enabled=st.torque_enabled, state=st.message)
        elif st.faulted and not alarm and policy == 'recover':
            tick = st.present_tick if st.present_tick is not None else self.bus.goals_tick.get(joint)
            if tick is not None:
                self.write_quiet(joint, 30, word(tick))
                self.bus.goals_tick[joint] = tick
            if self.write_quiet(joint, 34, word(self.config.torque_limit)):
                st.torque_limit = self._read_torque_limit(joint)
                if st.torque_limit == self.config.torque_limit:
                    st.faulted = 0
                    st.message = f'recovered: alarm cleared, torque limit {st.torque_limit} restored (read back)'
                    self.events.emit(EventKind.RECOVERED, joint=joint, servo_id=st.servo_id,
                                     torque_limit=st.torque_limit)

    def _read_torque_limit(self, joint: str) -> int | None:
        data = self.bus.read_register(joint, 34, 2, self.config.read_retries).data
        return u16(data) if data is not None else None

    def write_quiet(self, joint: str, address: int, data: list[int]) -> bool:
        """A write whose failure is an event, not an exception (a lost port still raises)."""
        try:
            self.bus.write_register(joint, address, data)
            return True
        except PortLostError:
            raise
        except BusError as exc:
            self.events.emit(EventKind.TRANSACTION_FAILED, joint=joint, servo_id=self.states[joint].servo_id,
                             address=address, reason=str(exc))
            return False
