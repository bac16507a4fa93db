"""The real driver core (dynamixel-sdk underneath) against the emulated AX-12A bus."""
import dataclasses
import math
import time

import pytest

from hexapod_driver import protocol as p
from hexapod_driver.bus import CommandError, DynamixelBus, EventKind, EventLog, ServoVerificationError
from hexapod_driver.config import DriverConfig
from hexapod_driver.emulator import BusEmulator
from hexapod_model.bus import BusError
from hexapod_model.description import ALL_JOINTS

# Generous reply timeout: the CI machine is shared and loaded; a lost reply then costs ~30 ms.
BASE = dict(timeout_margin_ms=25.0, read_retries=1, missing_after_failures=2, reprobe_period_s=0.05,
            reconnect_period_s=0.05, diagnostics_period_s=1e6, command_timeout_s=0.0)


def make_bus(robot, emu, clock=None, **kw):
    bus = (DynamixelBus(robot, DriverConfig(device=emu.port, **{**BASE, **kw})) if clock is None else
           DynamixelBus(robot, DriverConfig(device=emu.port, **{**BASE, **kw}), clock=clock, sleep=clock.sleep))
    bus.start()
    return bus


class ManualClock:
    """Simulated time for the driver and the emulator alike: it moves only when the test (or a
    sleep of the code under test) moves it, so timeouts are decided by the test, not by the load."""

    def __init__(self, t0: float = 1000.0):
        self.t = t0

    def __call__(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += max(dt, 0.0)

    advance = sleep


@pytest.fixture
def bus(robot, emu):
    b = make_bus(robot, emu)
    yield b
    b.close()


def steps_until(bus, cond, timeout=3.0):
    """Run the bus loop until cond(result) is true; returns every StepResult seen."""
    seen = []
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        r = bus.step()
        seen.append(r)
        if cond(r):
            return seen
    raise AssertionError(f'condition not met within {timeout} s; events: {[e.log_line() for e in events(seen)]}')


def events(results, kind=None):
    """The events of these step results (of one kind)."""
    return [e for r in results for e in r.events if kind is None or e.kind is kind]


def has(kind, **fields):
    """A step condition: an event of this kind with these fields."""
    return lambda r: any(all(e.fields.get(k) == v for k, v in fields.items()) for e in events([r], kind))


def sync_writes(emu):
    return [e for e in emu.log if e.instruction == p.SYNC_WRITE]


# ----------------------------------------------------------------------------- events
def test_events_are_typed_records_that_render_the_log_text():
    clock = ManualClock()
    log = EventLog(clock, throttle_s=1.0)
    failed = dict(joint='leg1_femur', servo_id=2, attempts=3, reason='no reply (timeout)')
    log.emit(EventKind.READ_FAILED, key='k', **failed)
    log.emit(EventKind.READ_FAILED, key='k', **failed)           # within the window: counted
    clock.advance(1.5)
    log.emit(EventKind.READ_FAILED, key='k', **failed)           # the next window says how many
    log.emit(EventKind.READ_FAILED, key='k', **failed)
    log.end('k')                                                 # the series ends: one more summary
    log.emit(EventKind.SERVO_ANSWERS, joint='leg1_femur', servo_id=2)
    ev = log.drain()
    assert [(e.kind, e.repeats, e.ended) for e in ev] == [
        (EventKind.READ_FAILED, 0, False), (EventKind.READ_FAILED, 1, False), (EventKind.READ_FAILED, 1, True),
        (EventKind.SERVO_ANSWERS, 0, False)]
    assert (ev[0].level, ev[0].joint, ev[0].servo_id, ev[3].level) == ('warn', 'leg1_femur', 2, 'info')
    assert ev[0].text() == 'leg1_femur (id 2): read failed after 3 attempts (no reply (timeout)); no position reported'
    assert ev[1].text() == ev[0].text() + ' (and 1 more times in the last 1 s)'
    assert ev[2].log_line() == '[read_failed] ' + ev[0].text() + ' (repeated 1 more times before it stopped)'
    assert log.drain() == []


# ----------------------------------------------------------------------------- start-up
def test_startup_configures_every_servo_and_holds_present_position(robot, emu, bus):
    rpt = robot.servo.rad_per_tick
    for bj in robot.bus.joints:
        s = emu.servo(bj.servo_id)
        lo, hi = robot.joint_limits(bj.joint)
        assert s.get('torque_enable') == 1 and s.get('torque_limit') == 1023
        assert s.get('return_delay_time') == 0
        assert [s.get(n) for n in ('cw_compliance_margin', 'ccw_compliance_margin', 'cw_compliance_slope',
                                   'ccw_compliance_slope')] == [robot.servo.compliance_margin_ticks] * 2 + \
            [robot.servo.compliance_slope_ticks] * 2
        # coxa [-1, 1] rad -> 512 -/+ 1 / (300 deg / 1024 in rad) = 512 -/+ 195.6 -> 316 .. 708
        assert (s.get('cw_angle_limit'), s.get('ccw_angle_limit')) == (round(512 + lo / rpt), round(512 + hi / rpt))
        assert s.get('goal_position') == 512                     # present position: nothing jumps
    assert emu.servo(1).get('cw_angle_limit') == 316 and emu.servo(1).get('ccw_angle_limit') == 708


def test_startup_writes_every_servo_law_register_from_the_description(robot, emu):
    # The firmware acts on compliance margins and slopes, the moving speed and the punch: whatever
    # an earlier program left in the servos' RAM, the driver writes the values the model assumes.
    old = {'cw_compliance_margin': 4, 'ccw_compliance_margin': 4, 'cw_compliance_slope': 64,
           'ccw_compliance_slope': 64, 'moving_speed': 300, 'punch': 200}
    for bj in robot.bus.joints:
        for name, v in old.items():
            emu.servo(bj.servo_id).set_register(name, v)
    b = make_bus(robot, emu)
    try:
        s = robot.servo
        want = {'cw_compliance_margin': s.compliance_margin_ticks, 'ccw_compliance_margin': s.compliance_margin_ticks,
                'cw_compliance_slope': s.compliance_slope_ticks, 'ccw_compliance_slope': s.compliance_slope_ticks,
                'moving_speed': s.moving_speed, 'punch': s.punch}
        for bj in robot.bus.joints:
            assert {n: emu.servo(bj.servo_id).get(n) for n in want} == want, bj.joint
        assert s.punch == p.REGISTERS['punch'].default == 32    # the AX-12A's own default, as the model has it
    finally:
        b.close()


def test_missing_servo_is_named_at_startup(robot, tmp_path):
    with BusEmulator(robot, absent_ids=(8,)) as emu:
        b = DynamixelBus(robot, DriverConfig(device=emu.port, **BASE))
        with pytest.raises(ServoVerificationError, match=r'no answer from leg3_femur \(id 8\)') as ei:
            b.start()
        assert ei.value.missing == [('leg3_femur', 8)] and ei.value.wrong == []
        b.close()
        assert all(s.get('torque_enable') == 0 for s in emu.servos)    # nothing was enabled


def test_wrong_model_is_named_at_startup(robot):
    with BusEmulator(robot, model_numbers={5: 18}) as emu:
        b = DynamixelBus(robot, DriverConfig(device=emu.port, **BASE))
        with pytest.raises(ServoVerificationError,
                           match=r'leg2_femur \(id 5\) reports model number 18, expected 12'):
            b.start()
        b.close()


def test_a_servo_at_status_return_level_0_is_set_to_2_at_startup(robot):
    with BusEmulator(robot) as emu:
        emu.servo(7).set_register('status_return_level', 0)          # answers PING only
        b = make_bus(robot, emu)
        b.close()
        said = [(e.kind, e.servo_id) for e in b.take_events() if e.kind is EventKind.NO_READ_REPLIES]
        assert said == [(EventKind.NO_READ_REPLIES, 7)]
        assert emu.servo(7).get('status_return_level') == 2


def test_a_read_reply_that_comes_late_at_startup_is_not_taken_for_status_return_level_0(robot, monkeypatch):
    # On a loaded host one reply can come after the driver gave up on it: the READ of the model
    # number after an answered PING. The servo does answer READs; nothing may say otherwise or
    # write its EEPROM.
    from hexapod_driver.bus.transport import Transport
    real, held = Transport.transact, []
    cfg = DriverConfig()                                             # the start-up reply timeout, ~52 ms
    late_s = 1.5e-3 * (cfg.startup_timeout_margin_ms + 2.0 * cfg.latency_timer_ms)   # during the retry

    def transact(self, sid, instruction, params, n_reply, expect_reply=True):
        late = sid == 7 and instruction == p.READ and params[0] == 0 and not held
        if late:
            held.append(sid)
            emu.faults.set_reply_latency(late_s)                     # after the start-up reply timeout
        try:
            return real(self, sid, instruction, params, n_reply, expect_reply)
        finally:
            if late:
                emu.faults.set_reply_latency(0.0)
    monkeypatch.setattr(Transport, 'transact', transact)
    with BusEmulator(robot) as emu:
        b = make_bus(robot, emu)
        b.close()
        kinds = {e.kind for e in b.take_events()}
        reads = [e for e in emu.log if e.servo_id == 7 and e.instruction == p.READ and e.address == 0]
        assert held and reads[0].replied
        assert EventKind.NO_READ_REPLIES not in kinds
        assert not [e for e in emu.log if e.instruction == p.WRITE and e.address == 16]
        assert len(reads) == 2 and reads[1].data == b'\x03'          # asked again, a byte more


def test_replies_late_now_and_then_are_not_taken_for_the_adapters_latency_timer(robot):
    # The adapter's latency timer holds back every reply, a loaded host only some: here the PINGs
    # of 10 servos of 18 are answered 20 ms late (within start-up's reply timeout), the others at once.
    with BusEmulator(robot) as emu:
        for sid in range(1, 11):
            emu.faults.hold_replies(0.02, ids=sid, count=1)            # a servo's first reply: its PING
        b = make_bus(robot, emu)
        b.close()
        held = [e for e in emu.log if e.instruction == p.PING and e.t_reply - e.t >= 0.02]
        assert len(held) == 10                                       # the median PING was late
        assert EventKind.LATE_REPLIES not in {e.kind for e in b.take_events()}


def test_config_validation_names_the_parameter(robot):
    with pytest.raises(ValueError, match="fault_policy: 'hold' no longer exists"):
        DynamixelBus(robot, DriverConfig(fault_policy='hold'))
    with pytest.raises(ValueError, match='fault_policy'):
        DynamixelBus(robot, DriverConfig(fault_policy='explode'))
    with pytest.raises(ValueError, match='torque_limit'):
        DynamixelBus(robot, DriverConfig(torque_limit=0))


# ----------------------------------------------------------------------------- commands
def test_goals_reach_the_servos_with_mounting_direction_and_offset(robot, emu):
    joints = tuple(dataclasses.replace(j, direction=-1, offset_ticks=10) if j.joint == 'leg1_femur' else j
                   for j in robot.bus.joints)
    mounted = dataclasses.replace(robot, bus=dataclasses.replace(robot.bus, joints=joints))   # as an overlay does
    b = make_bus(mounted, emu)
    try:
        assert b.set_command(['leg1_femur', 'leg4_tibia'], [0.3, -0.2]) == []
        n0 = len(sync_writes(emu))
        steps_until(b, lambda r: r.wrote)
        rpt = robot.servo.rad_per_tick
        assert emu.servo(2).get('goal_position') == round(512 - 0.3 / rpt + 10)
        assert emu.servo(12).get('goal_position') == round(512 - 0.2 / rpt)
        assert len(sync_writes(emu)) == n0 + 1                    # one SYNC_WRITE for both
        assert emu.servo(1).get('goal_position') == 512           # untouched joints keep their goal
    finally:
        b.close()


def test_bad_commands_never_reach_the_bus(robot, emu, bus):
    n0 = len(sync_writes(emu))
    with pytest.raises(CommandError, match='not finite'):
        bus.set_command(['leg1_coxa', 'leg1_femur'], [0.1, math.nan])
    with pytest.raises(CommandError, match="unknown joint 'leg7_coxa'"):
        bus.set_command(['leg7_coxa'], [0.0])
    with pytest.raises(CommandError, match='2 joint names but 1 positions'):
        bus.set_command(['leg1_coxa', 'leg1_femur'], [0.0])
    with pytest.raises(CommandError, match='duplicate'):
        bus.set_command(['leg1_coxa', 'leg1_coxa'], [0.0, 0.1])
    clock = ManualClock()
    stale = DynamixelBus(robot, DriverConfig(device=emu.port, **{**BASE, 'command_timeout_s': 0.5}), clock=clock)
    with pytest.raises(CommandError, match=r'stale command: stamped 0.501 s ago \(command_timeout_s=0.5\)'):
        stale.set_command(['leg1_coxa'], [0.0], stamp=clock() - 0.501)
    assert stale.set_command(['leg1_coxa'], [0.0], stamp=clock() - 0.499) == []     # just fresh enough
    strict = DynamixelBus(robot, DriverConfig(device=emu.port, **{**BASE, 'limit_policy': 'reject'}))
    with pytest.raises(CommandError, match=r'leg1_coxa: goal 1.5000 rad outside the joint limits \[-1.0, 1.0\]'):
        strict.validate_goals({'leg1_coxa': 1.5})
    for _ in range(20):
        bus.step()
    assert len(sync_writes(emu)) == n0
    assert all(s.get('goal_position') == 512 for s in emu.servos)


def test_goal_outside_limits_is_clamped_with_a_warning(robot, emu, bus):
    warnings = bus.set_command(['leg1_coxa'], [1.5])
    assert warnings and 'clamped to 1.0' in warnings[0]
    steps_until(bus, lambda r: r.wrote)
    assert emu.servo(1).get('goal_position') == 708             # the CCW angle limit, not beyond


# ----------------------------------------------------------------------------- reads
def test_reads_follow_the_schedule_with_truthful_stamps(robot, emu, bus):
    bus.set_command(['leg1_femur', 'leg6_femur', 'leg3_femur'], [0.8, 0.8, 0.8])   # moving while read
    sched = ('leg1_femur', 'leg6_femur', 'leg3_femur')
    bus.set_schedule(sched)
    emu.log.clear()
    results = steps_until(bus, lambda r: False if len(emu.log) < 40 else True)
    samples = [s for r in results for s in r.samples]
    assert [s.joint for s in samples] == [sched[k % 3] for k in range(len(samples))]
    reads = [e for e in emu.log if e.instruction == p.READ and e.address == 36]
    ids = {'leg1_femur': 2, 'leg6_femur': 17, 'leg3_femur': 8}
    assert [e.servo_id for e in reads] == [ids[s.joint] for s in samples]
    ticks = {s.tick for s in samples}
    assert len(ticks) > 3                                         # the femurs really moved during the test
    for s, e in zip(samples, reads):
        # the READ arrived at the emulator after the stamp and before the reply was complete
        assert s.stamp <= e.wall <= s.stamp + s.t_com_s
        assert s.tick == e.reply_params[0] | e.reply_params[1] << 8     # exactly what the servo sampled
        assert s.theta_rad == pytest.approx((s.tick - 512) * robot.servo.rad_per_tick)


def test_empty_schedule_restores_all_joints_and_unknown_is_rejected(bus):
    with pytest.raises(CommandError, match='leg1_knee'):
        bus.set_schedule(['leg1_femur', 'leg1_knee'])
    bus.set_schedule(['leg2_coxa'])
    assert bus.set_schedule([]) == ALL_JOINTS


def test_servobus_protocol_runs_on_the_driver(robot, emu, bus):
    t_w = bus.sync_write({'leg5_coxa': 0.2})
    assert abs(t_w - bus.now()) < 1.0
    bus.wait_until(bus.now() + 0.3)                                # 0.2 rad = 68 ticks at ~1200 ticks/s
    theta, t = bus.read_position('leg5_coxa')
    assert theta == pytest.approx(0.2, abs=robot.servo.rad_per_tick) and t > t_w
    with pytest.raises(CommandError):
        bus.sync_write({'leg5_coxa': math.inf})


# ----------------------------------------------------------------------------- faults
def test_dropped_and_corrupt_replies_are_retried_counted_and_never_invented(emu, bus):
    bus.timing.snapshot(reset=True)
    emu.faults.drop_replies(ids=2, count=1)
    theta, _ = bus.read_position('leg1_femur')                   # retry succeeds
    emu.faults.corrupt_replies(ids=2, count=1)
    theta2, _ = bus.read_position('leg1_femur')
    assert theta == theta2 == 0.0
    assert bus.timing.snapshot().failed_reads == 2
    emu.faults.drop_replies(ids=2, count=2)                      # more than the retry budget
    with pytest.raises(BusError, match=r'leg1_femur \(id 2\): no valid reply after 2 attempts'):
        bus.read_position('leg1_femur')
    bus.take_events()
    bus.read_position('leg1_femur')                              # answers again: failure streak reset
    bus.set_schedule(['leg1_femur'])
    bus.throttle_s = 0.0                                         # a new series is logged at once
    n0 = bus.states['leg1_femur'].failed_attempts
    emu.faults.corrupt_replies(ids=2, count=2)
    r = bus.step()
    assert r.samples == [] and [e.joint for e in events([r], EventKind.READ_FAILED)] == ['leg1_femur']
    assert bus.states['leg1_femur'].failed_attempts == n0 + 2
    assert bus.step().samples[0].joint == 'leg1_femur'
    bus.throttle_s = 60.0
    emu.faults.corrupt_replies(ids=2, count=2)                   # again within throttle_s: counted, not logged
    r = bus.step()
    assert r.samples == [] and not events([r]) and bus.states['leg1_femur'].failed_attempts == n0 + 4
    assert bus.step().samples
    bus.throttle_s = 0.0
    emu.faults.corrupt_replies(ids=2, count=2)                   # window over: logged with the summary
    r = bus.step()
    assert [(e.joint, e.repeats) for e in events([r], EventKind.READ_FAILED)] == [('leg1_femur', 1)]


def test_a_late_reply_is_not_taken_for_the_answer(emu, bus):
    # dynamixel-sdk's own readTxRx takes the first packet with the right ID: behind a stale, empty
    # status packet (FF FF 02 02 00 FB) it returns that packet's checksum byte as "data"
    from dynamixel_sdk import COMM_SUCCESS, PacketHandler
    emu.faults.stale_replies(ids=2, count=1)
    data, result, _err = PacketHandler(1.0).readTxRx(bus.port, 2, 36, 2)
    assert (result, data) == (COMM_SUCCESS, [0xFB])
    bus.timing.snapshot(reset=True)
    emu.faults.stale_replies(ids=2, count=1)
    theta, _ = bus.read_position('leg1_femur')
    assert theta == 0.0 and bus.timing.snapshot().failed_reads == 0 and emu.faults.stale == 2


def test_a_reply_later_than_all_attempts_is_not_taken_for_the_next_read_of_the_servo(robot):
    # Protocol 1.0 has no sequence numbers: the reply to a read that timed out on every attempt
    # comes during the next read of the same servo, which asked for the same register.
    from hexapod_driver.emulator.backends import IdealServoBackend

    class Dial(IdealServoBackend):                                # the horn is where the test says
        tick = None

        def sample(self, t, slot):
            return (float(self.tick), 0.0) if self.tick is not None else super().sample(t, slot)
    dial = Dial(robot)
    with BusEmulator(robot, backend=dial) as emu:
        b = make_bus(robot, emu)
        try:
            dial.tick = 300
            emu.faults.hold_replies(0.5, ids=1, count=1)            # past both attempts; the ones behind wait
            with pytest.raises(BusError, match='no valid reply after 2 attempts'):
                b.read_position('leg1_coxa')
            dial.tick = 700
            with b.transport.reply_margin(3000.0):                  # the held reply comes during this read
                theta, _stamp = b.read_position('leg1_coxa')
        finally:
            b.close()
        reads = [e for e in emu.log if e.servo_id == 1 and e.instruction == p.READ and e.address is not None
                 and e.address <= 36 < e.address + e.data[0]][-3:]
        first, nxt = reads[0], reads[2]
        assert nxt.wall < first.wall_reply < nxt.wall_reply          # it came while the next read waited
        assert first.reply_params == bytes([300 & 0xFF, 300 >> 8])
        assert theta == b.to_theta('leg1_coxa', 700)                 # the next read's own answer
        assert len(nxt.data) == 1 and nxt.data[0] not in {r.data[0] for r in reads[:2]}   # of its own length


def test_reads_keep_away_from_the_lengths_of_unanswered_requests_until_the_bus_answers(emu, bus):
    def asked():
        return [e.data[0] for e in emu.log if e.servo_id == 1 and e.instruction == p.READ][-1]
    emu.faults.remove_servo(1)
    lengths = []
    for _ in range(3):
        assert bus.read_register('leg1_coxa', 36, 2, retries=0).data is None
        lengths.append(asked())
    emu.faults.restore_servo(1)
    assert bus.read_register('leg1_coxa', 36, 2, retries=0).data is not None
    lengths.append(asked())
    assert bus.read_register('leg1_coxa', 36, 2, retries=0).data is not None    # answered: all came or never will
    lengths.append(asked())
    assert lengths == [2, 3, 4, 5, 2]


def test_a_servo_silent_for_every_length_the_table_has_is_asked_for_its_own_again(emu, bus):
    emu.faults.remove_servo(1)
    for _ in range(p.TABLE_SIZE):
        assert bus.read_register('leg1_coxa', 36, 2, retries=0).data is None
    asked = [(e.address, e.data[0]) for e in emu.log if e.servo_id == 1 and e.instruction == p.READ][-p.TABLE_SIZE:]
    assert [n for _a, n in asked] == [*range(2, p.TABLE_SIZE + 1), 2]      # 49 lengths, then none left
    assert all(a + n <= p.TABLE_SIZE and a <= 36 for a, n in asked)       # inside the table, position included


def test_vanished_servo_is_reported_skipped_and_welcomed_back(emu, bus):
    bus.set_schedule(['leg2_coxa', 'leg2_femur'])
    emu.faults.remove_servo(4)                                    # leg2_coxa
    seen = steps_until(bus, has(EventKind.SERVO_MISSING))
    assert bus.states['leg2_coxa'].missing and not bus.states['leg2_coxa'].responding
    assert [(e.joint, e.servo_id) for e in events(seen, EventKind.SERVO_MISSING)] == [('leg2_coxa', 4)]
    more = [bus.step() for _ in range(10)]                       # re-probes are 50 ms apart: skipped meanwhile
    assert sum(len(r.samples) for r in more) >= 8
    assert all(s.joint == 'leg2_femur' for r in more for s in r.samples)
    emu.faults.restore_servo(4)
    back = steps_until(bus, has(EventKind.SERVO_ANSWERS, joint='leg2_coxa'))
    assert any(s.joint == 'leg2_coxa' for r in back for s in r.samples)
    assert not bus.states['leg2_coxa'].missing


@pytest.mark.parametrize('policy', ['limp', 'recover'])
def test_overheating_triggers_the_fault_policy(robot, emu, policy):
    b = make_bus(robot, emu, fault_policy=policy)
    try:
        b.set_command(['leg2_tibia'], [0.5])                     # id 6, moving
        b.set_schedule(['leg2_tibia'])
        steps_until(b, lambda r: r.wrote)
        emu.faults.set_temperature(6, 85.0)
        seen = steps_until(b, has(EventKind.FAULT, joint='leg2_tibia', alarm_bits=p.ERR_OVERHEATING, policy=policy))
        st = b.states['leg2_tibia']
        assert st.faulted & p.ERR_OVERHEATING and st.error_bits & p.ERR_OVERHEATING
        s = emu.servo(6)
        assert s.get('torque_limit') == 0                         # the servo's own alarm shutdown
        assert st.torque_limit == 0 and 'torque limit 0 (limp)' in st.message   # said as it is
        if policy == 'limp':
            assert s.get('torque_enable') == 0 and not st.torque_enabled
        n0 = len(sync_writes(emu))
        w = b.set_command(['leg2_tibia'], [-0.5])
        assert w and 'ignored, servo in fault' in w[0]
        for _ in range(5):
            b.step()
        assert len(sync_writes(emu)) == n0
        emu.faults.set_temperature(6, 40.0)
        steps_until(b, lambda r: any(s.joint == 'leg2_tibia' for s in r.samples) and
                    not b.states['leg2_tibia'].error_bits)
        if policy == 'recover':
            steps_until(b, lambda r: b.states['leg2_tibia'].faulted == 0, timeout=1.0)
            assert s.get('torque_limit') == 1023 and s.torque_on
            assert s.get('goal_position') == b.states['leg2_tibia'].present_tick   # no jump on recovery
            assert 'torque limit 1023 restored' in b.states['leg2_tibia'].message
            assert b.set_command(['leg2_tibia'], [-0.5]) == []
        else:
            assert b.states['leg2_tibia'].faulted                  # limp: stays out until restart
            assert s.get('torque_limit') == 0
        assert any(e.joint == 'leg2_tibia' and e.servo_id == 6 and e.fields['error_bits'] & p.ERR_OVERHEATING
                   for e in events(seen, EventKind.ERROR_BITS))
    finally:
        b.close()


def test_diagnostics_round_reports_every_servo_with_error_bits(robot, emu):
    b = make_bus(robot, emu, diagnostics_period_s=0.05)
    try:
        emu.faults.set_overload(13)
        emu.faults.set_voltage(8.0, servo_id=14)                  # inside the 6.0 .. 14.0 V limits
        emu.faults.set_voltage(5.0, servo_id=15)                  # below them
        res = steps_until(b, lambda r: r.diagnostics is not None)
        diag = {d.joint: d for d in res[-1].diagnostics}
        assert len(diag) == 18
        ok = diag['leg1_coxa']
        assert (ok.temperature_c, ok.voltage_v, ok.error_bits, ok.responding, ok.torque_enabled) == \
            (30.0, 12.0, 0, True, True)
        ol = diag['leg5_coxa']                                     # id 13
        assert ol.error_bits & p.ERR_OVERLOAD and 'overload' in ol.message
        assert diag['leg5_tibia'].error_bits & p.ERR_INPUT_VOLTAGE  # id 15 at 5 V
        assert diag['leg5_femur'].error_bits == 0 and diag['leg5_femur'].voltage_v == pytest.approx(8.0)
    finally:
        b.close()


def test_port_vanishes_is_survived_and_reconnected(robot, emu, bus):
    bus.set_schedule(['leg1_coxa'])
    assert bus.step().samples
    emu.disconnect()
    lost = steps_until(bus, has(EventKind.PORT_LOST))
    assert not bus.port_ok and all(not r.samples for r in lost)
    failed = steps_until(bus, has(EventKind.RECONNECT_FAILED))
    assert all(not r.samples for r in failed)                     # no invented positions meanwhile
    emu.power_cycle()                                              # the servos lost power too
    assert emu.servo(1).get('torque_enable') == 0
    emu.reconnect()
    back = steps_until(bus, lambda r: bool(r.samples))
    assert events(back, EventKind.RECONNECTED)
    assert all(s.get('torque_enable') == 1 for s in emu.servos)    # re-verified and re-configured


def test_stale_command_stream_holds_position(robot, emu):
    """The driver's clock is the test's (ManualClock): the command goes stale when the test says so,
    not when a loaded machine happens to take 0.1 s; what the servo did is read from the emulator."""
    clock = ManualClock()
    b = make_bus(robot, emu, clock=clock, command_timeout_s=0.1)
    try:
        emu.servo(1).set_register('moving_speed', 100)              # 11 rpm = 227 ticks/s
        b.set_command(['leg1_coxa'], [0.9])                        # 461 ticks away: ~2 s
        steps_until(b, lambda r: r.wrote)
        t_cmd = clock()
        clock.advance(0.09)                                        # younger than the timeout: nothing
        assert not events([b.step() for _ in range(3)], EventKind.HOLDING)
        # wait (on a condition) until the servo has left its start, so "held where it was" is testable
        slot = emu.servo(1).slot
        t_end = time.monotonic() + 10.0
        while emu.backend.sample(emu.now(), slot)[0] < 516 and time.monotonic() < t_end:
            time.sleep(0.005)
        emu.log.clear()
        clock.advance(0.06)
        seen = [b.step()]
        hold = events(seen, EventKind.HOLDING)
        assert [(e.fields['idle_s'], e.fields['timeout_s'], e.fields['held']) for e in hold] == \
            [(pytest.approx(clock() - t_cmd), 0.1, 18)]
        goal = emu.servo(1).get('goal_position')
        assert 512 < goal < b.to_tick('leg1_coxa', 0.9)           # held where it was, not at the old goal
        # the hold wrote exactly the position servo 1 reported to the hold's read, in one SYNC_WRITE
        read = next(e for e in emu.log if e.servo_id == 1 and e.instruction == p.READ and e.address == 36)
        assert read.reply_params[0] | read.reply_params[1] << 8 == goal
        assert [e.instruction for e in emu.log].count(p.SYNC_WRITE) == 1
        assert emu.present_tick(1, t=emu.now() + 1.0) == goal      # the servo's model comes to rest there
    finally:
        b.close()


def test_emergency_stop_turns_torque_off_and_refuses_commands(emu, bus):
    ok, msg = bus.emergency_stop()
    assert ok, msg
    assert all(s.get('torque_enable') == 0 for s in emu.servos)
    with pytest.raises(CommandError, match='emergency stop'):
        bus.set_command(['leg1_coxa'], [0.1])
    assert bus.step().samples                                     # still reading


def test_close_turns_torque_off(robot, emu):
    b = make_bus(robot, emu)
    assert all(s.get('torque_enable') == 1 for s in emu.servos)
    emu.faults.drop_replies(ids=3, count=1)                        # even with a flaky confirmation
    assert b.close() == []
    assert all(s.get('torque_enable') == 0 for s in emu.servos)
    assert b.close() == []                                         # idempotent


@pytest.mark.realtime
def test_reads_are_paced_and_goals_do_not_wait_for_the_read_slot(robot, emu):
    import threading
    b = make_bus(robot, emu, read_period_s=0.1)     # long periods: scheduling jitter on a loaded machine is far smaller
    try:
        b.set_schedule(['leg1_coxa'])
        samples = [s for _ in range(5) for s in b.step().samples]
        stamps = [s.stamp for s in samples]
        assert len(stamps) == 5 and all(t1 - t0 >= 0.1 - 1e-4 for t0, t1 in zip(stamps, stamps[1:]))
        sent = []
        timer = threading.Timer(0.02, lambda: sent.append((time.time(), b.set_command(['leg1_coxa'], [0.1]))))
        emu.log.clear()
        timer.start()
        r = b.step()                                 # waits for the read slot ~100 ms after the last read
        timer.join()
        assert r.wrote and r.samples
        write = next(e for e in emu.log if e.instruction == p.SYNC_WRITE)
        read = next(e for e in emu.log if e.instruction == p.READ)
        # written when it came, before the read slot the driver's own stamps set (a timer late by up
        # to 80 ms on a loaded machine still passes), and the read not before its slot
        slot = stamps[-1] + 0.1
        assert sent[0][0] <= write.wall < slot <= read.wall, (sent[0][0] - slot, write.wall - slot, read.wall - slot)
    finally:
        b.close()
