"""Servo set-up: verification at start-up and the registers the driver writes before it runs.

:meth:`ServoSetup.verify` PINGs every joint's servo and checks model number 12
(:class:`ServoVerificationError` names each missing or wrong servo) and measures the reply
latency. :meth:`ServoSetup.configure` writes what the driver needs: status return level 2,
return delay time, alarm shutdown and the angle limits (EEPROM, only when they differ), the servo
law from the robot description (compliance margin and slope, moving speed, punch) and the torque
limit; :meth:`ServoSetup.hold` then sets each goal to the present position and writes torque
enable (no jump when torque comes on).
"""
from __future__ import annotations

from typing import Mapping, Protocol, Sequence, runtime_checkable

from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS

from hexapod_driver import protocol as p
from hexapod_driver.bus.events import EventKind
from hexapod_driver.bus.host import BusHost
from hexapod_driver.bus.transport import ALARM_BITS, result_text
from hexapod_driver.protocol import u16, word
from hexapod_model.bus import BusError
from hexapod_model.description import BusJoint, Robot

AX12A_BAUD_RATES = '1000000 factory default, 500000, 400000, 250000, 200000, 117647, 57600, 19200, 9600'


class ServoVerificationError(BusError):
    """Start-up found servos that do not answer or are not AX-12As; ``missing``/``wrong`` list them."""

    def __init__(self, message: str, missing: Sequence[tuple[str, int]] = (),
                 wrong: Sequence[tuple[str, int, int]] = ()):
        super().__init__(message)
        self.missing = list(missing)
        self.wrong = list(wrong)


@runtime_checkable
class SetupHost(BusHost, Protocol):
    """What :class:`ServoSetup` uses of the bus it sets up (:class:`~hexapod_driver.bus.core.DynamixelBus`)."""

    robot: Robot
    mount: Mapping[str, BusJoint]
    goals_tick: dict[str, int]
    baud_rate: int
    margin: int
    slope: int
    punch: int
    moving_speed: int
    reply_latency_s: float
    last_failure: str

    def attempts(self, retries: int | None = None) -> int: ...

    def angle_limits_tick(self, joint: str) -> tuple[int, int]: ...


class ServoSetup:
    """Verification and configuration of the servos of one :class:`DynamixelBus` (its lock held)."""

    def __init__(self, bus: SetupHost):
        self.bus = bus
        self.transport = bus.transport
        self.config = bus.config

    # ------------------------------------------------------------------ verification
    def verify(self) -> None:
        """PING every joint's servo and check its model number; raise naming every bad one.

        Also measures the reply latency (the fastest PING round trip minus its wire time: the
        adapter's latency timer holds back every reply, a loaded host only some); replies far
        later than the wire time mean the USB adapter's latency timer is not 1 ms: the reply
        timeout is widened to cover it (so no reply is declared lost and then taken for the answer
        to a later request) and a warning says what to fix."""
        bus = self.bus
        missing, wrong, rtts = [], [], []
        attempts = bus.attempts()
        for j in bus.joints:
            sid = bus.mount[j].servo_id
            model, result, why = None, None, ''
            for k in range(attempts):
                # only a first PING is timed: a retry's answer may be the late one to the PING before
                model, result, why = self._ping(sid, rtts if k == 0 else None)
                if result == COMM_SUCCESS:
                    break
            if result != COMM_SUCCESS:
                missing.append((j, sid, why))
            elif model != p.AX12A_MODEL_NUMBER:
                wrong.append((j, sid, model))
        if missing or wrong:
            raise ServoVerificationError(self._verification_text(missing, wrong, attempts),
                                         [(j, i) for j, i, _w in missing], wrong)
        self._check_latency(rtts)

    def _verification_text(self, missing, wrong, attempts: int) -> str:
        parts = []
        if len(missing) == len(self.bus.joints):
            parts.append(
                f'no servo answers at {self.transport.baud_rate} baud (tried ids '
                f'{", ".join(str(i) for _j, i, _w in missing)}, {attempts} attempts each). Check the servo '
                f'power and cable; if the servos are set to another baud rate (register 4), find them with '
                f'`./hexapod run hexapod_driver servo_tool --device {self.config.device} --baud <rate> scan` '
                f'(AX-12A rates: {AX12A_BAUD_RATES}) and set bus.baud_rate in the robot description (an '
                f'overlay) to match')
        elif missing:
            parts.append('no answer from ' + ', '.join(
                f'{j} (id {i})' + (f' [{w}]' if w else '') for j, i, w in missing))
        if wrong:
            parts.append('wrong model: ' + ', '.join(
                f'{j} (id {i}) reports model number {m}, expected {p.AX12A_MODEL_NUMBER} (AX-12A)'
                for j, i, m in wrong))
        return f'servo verification on {self.config.device} failed: ' + '; '.join(parts)

    def _check_latency(self, rtts: list[float]) -> None:
        if not rtts:
            return
        wire = 12 * p.BITS_PER_BYTE / self.transport.baud_rate            # PING: 6 bytes out, 6 back
        late = max(0.0, min(rtts) - wire)           # the adapter delays every reply, host load some
        self.bus.reply_latency_s = late
        if late * 1e3 > max(2.0, 2.0 * self.config.latency_timer_ms + 1.0):
            port = self.transport.port
            old = port.latency_timer_ms
            port.latency_timer_ms = max(old, (late * 1e3 + 1.0) / 2.0)       # the timeout counts it twice
            self.bus.events.emit(EventKind.LATE_REPLIES, late_ms=late * 1e3, rtt_ms=(late + wire) * 1e3,
                                 pings=len(rtts), wire_us=wire * 1e6, old_ms=old, new_ms=port.latency_timer_ms)

    def _ping(self, sid: int, rtts: list[float] | None = None) -> tuple[int | None, int, str]:
        """PING, then READ the model number: (model, result, what failed)."""
        tr = self.transport
        _data, result, _err = tr.transact(sid, p.PING, [], 0)
        if result != COMM_SUCCESS:
            return None, result, f'PING: {result_text(result)}'
        if rtts is not None:
            rtts.append(tr.last_ok_t - tr.last_tx_time)
        # every attempt one byte longer (Transport.read): a reply that comes late, on a loaded
        # host, is not taken for the answer to the next attempt, nor for a missing reply
        attempts = self.bus.attempts()
        read = tr.read(sid, 0, 2, attempts)
        if read.data is None and read.failures == [result_text(COMM_RX_TIMEOUT)] * attempts:
            # answers PING but never READ: status return level 0. Set it to 2 (EEPROM; the write
            # itself is not answered at level 0) and ask again.
            tr.send(sid, p.WRITE, [16, p.RETURN_ALL])
            self.bus.events.emit(EventKind.NO_READ_REPLIES, servo_id=sid, value=p.RETURN_ALL)
            read = tr.read(sid, 0, 2, attempts)
        if read.data is None:
            last = read.failures[-1]
            return (None, COMM_RX_TIMEOUT if last == result_text(COMM_RX_TIMEOUT) else COMM_RX_CORRUPT,
                    f'READ of the model number: {last}')
        return u16(read.data), COMM_SUCCESS, ''

    # ------------------------------------------------------------------ configuration
    def configure(self, enable_torque: bool) -> None:
        """Configure every servo, hold it at its present position, torque enable as asked."""
        bus = self.bus
        for j in bus.joints:
            self._ensure_status_return_level(j)
            self._ensure_eeprom(j, 'return_delay_time', self.config.return_delay_time)
            self._ensure_eeprom(j, 'alarm_shutdown', ALARM_BITS)
            if self.config.write_angle_limits:
                cw, ccw = bus.angle_limits_tick(j)
                old = self._read(j, 6, 4, 'the angle limits (address 6)')
                if (u16(old[:2]), u16(old[2:])) != (cw, ccw):       # both in one write: never cw > ccw
                    bus.write_register(j, 6, word(cw) + word(ccw))
            bus.write_register(j, 26, [bus.margin, bus.margin, bus.slope, bus.slope])
            bus.write_register(j, 32, word(bus.moving_speed))
            bus.write_register(j, 34, word(self.config.torque_limit))
            bus.write_register(j, 48, word(bus.punch))
            st = bus.states[j]
            st.torque_limit = self.config.torque_limit
            st.responding, st.missing, st.consecutive_failures, st.faulted = True, False, 0, 0
        self.hold(enable_torque)

    def hold(self, enable_torque: bool) -> None:
        """Set every goal to the present position (inside the angle limits) and write torque enable."""
        bus = self.bus
        for j in bus.joints:
            sid = bus.mount[j].servo_id
            tick = u16(self._read(j, 36, 2, 'the present position'))
            lo, hi = bus.angle_limits_tick(j) if self.config.write_angle_limits else (0, bus.robot.servo.max_tick)
            goal = min(hi, max(lo, tick))
            if goal != tick:
                bus.events.emit(EventKind.GOAL_OUTSIDE_LIMITS, joint=j, servo_id=sid, tick=tick, low=lo, high=hi,
                                goal=goal)
            bus.write_register(j, 30, word(goal))
            bus.write_register(j, 24, [int(enable_torque)])
            bus.goals_tick[j] = goal
            st = bus.states[j]
            st.present_tick, st.torque_enabled = tick, enable_torque
            st.message = 'configured' if enable_torque else 'configured, torque off'

    def _read(self, joint: str, address: int, n: int, what: str) -> bytes:
        data = self.bus.read_register(joint, address, n).data
        if data is None:
            raise BusError(f'{joint} (id {self.bus.mount[joint].servo_id}): cannot read {what}: '
                           f'{self.bus.last_failure}')
        return data

    def _ensure_status_return_level(self, joint: str) -> None:
        """Status return level (address 16) = 2, so that every write is answered and confirmed.

        At level 1 a servo answers only READ (and PING); at 0 only PING. The write that raises the
        level is therefore not answered: it is sent without waiting and checked by reading back."""
        bus = self.bus
        sid = bus.mount[joint].servo_id
        data = self._read(joint, 16, 1, 'the status return level (address 16)')
        if data[0] == p.RETURN_ALL:
            return
        for _ in range(bus.attempts()):
            self.transport.send(sid, p.WRITE, [16, p.RETURN_ALL])
            bus.sleep(0.002)                       # an unanswered EEPROM write: give it time
            back = bus.read_register(joint, 16, 1).data
            if back is not None and back[0] == p.RETURN_ALL:
                bus.events.emit(EventKind.STATUS_RETURN_LEVEL_SET, joint=joint, servo_id=sid, was=data[0],
                                meaning='replies to PING only' if data[0] == 0 else 'replies to reads only',
                                value=p.RETURN_ALL)
                return
        raise BusError(f'{joint} (id {sid}): status return level is {data[0]} and could not be set to '
                       f'{p.RETURN_ALL} (address 16): {bus.last_failure or "read back a different value"}')

    def _ensure_eeprom(self, joint: str, name: str, value: int) -> None:
        r = p.register(name)
        data = self._read(joint, r.address, r.size, f'{name} (address {r.address})')
        if int.from_bytes(bytes(data), 'little') != value:      # write EEPROM only when it differs
            self.bus.write_register(joint, r.address, list(int(value).to_bytes(r.size, 'little')))
