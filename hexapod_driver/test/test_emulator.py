"""The AX-12A bus emulator, spoken to byte for byte over its pseudo-terminal (no driver involved)."""
import math
import time

import pytest
import serial

from hexapod_driver import protocol as p
from hexapod_driver.emulator import BusEmulator, IdealServoBackend, ServoBusBackend
from hexapod_model.description import ALL_JOINTS
from hexapod_model.servo import servo_tick


class Line:
    """A bare master on the pty: write instruction packets, read status packets."""

    def __init__(self, port):
        self.ser = serial.Serial(port, 1_000_000, timeout=0.5)

    def send(self, sid, instruction, params=(), raw=None):
        self.ser.reset_input_buffer()
        self.ser.write(raw if raw is not None else p.encode_instruction(sid, instruction, params))

    def receive(self, timeout=0.5):
        self.ser.timeout = timeout
        head = self.ser.read(4)
        if len(head) < 4:
            return None
        return p.decode_packet(head + self.ser.read(head[3]))

    def txrx(self, sid, instruction, params=()):
        self.send(sid, instruction, params)
        return self.receive()

    def read(self, sid, address, n):
        return self.txrx(sid, p.READ, [address, n])

    def close(self):
        self.ser.close()


@pytest.fixture
def line(emu):
    ln = Line(emu.port)
    yield ln
    ln.close()


def u16(b):
    return b[0] | b[1] << 8


def test_all_18_servos_answer_ping_with_model_12(emu, line):
    for bj in emu.robot.bus.joints:
        st = line.txrx(bj.servo_id, p.PING)
        assert st is not None and st.servo_id == bj.servo_id and st.code == 0 and st.params == b''
        assert u16(line.read(bj.servo_id, 0, 2).params) == p.AX12A_MODEL_NUMBER
    line.send(77, p.PING)
    assert line.receive(timeout=0.05) is None          # nobody has id 77


def test_write_read_back_and_ram_eeprom_semantics(emu, line):
    assert line.txrx(3, p.WRITE, [5, 0]).code == 0               # return delay (EEPROM)
    assert line.txrx(3, p.WRITE, [26, 4, 4, 64, 64]).code == 0   # margins + slopes (RAM), 4 bytes at once
    assert line.read(3, 26, 4).params == bytes([4, 4, 64, 64])
    emu.power_cycle()
    assert line.read(3, 5, 1).params == b'\x00'                  # EEPROM kept
    assert line.read(3, 26, 4).params == bytes([1, 1, 32, 32])   # RAM back to power-up values
    assert u16(line.read(3, 34, 2).params) == 1023               # torque limit = max torque at power-up


@pytest.mark.parametrize('params, err', [
    ([36, 0, 2], p.ERR_RANGE),          # present position is read-only
    ([10, 1], p.ERR_RANGE),             # reserved address
    ([30, 0, 4], p.ERR_RANGE),          # goal 1024 > 1023
    ([24, 2], p.ERR_RANGE),             # torque enable is 0/1
    ([49, 0, 0], p.ERR_RANGE),          # past the end of the table
])
def test_bad_writes_are_refused_with_an_error_bit_and_change_nothing(emu, line, params, err):
    before = bytes(emu.servo(2).mem)
    st = line.txrx(2, p.WRITE, params)
    assert st.code == err
    assert bytes(emu.servo(2).mem) == before


def test_goal_outside_angle_limits_sets_angle_error_and_is_not_applied(emu, line):
    assert line.txrx(4, p.WRITE, [6, 0, 1, 0, 3]).code == 0      # CW 256, CCW 768
    st = line.txrx(4, p.WRITE, [30, 0xE8, 0x03])                  # goal 1000
    assert st.code == p.ERR_ANGLE_LIMIT
    assert emu.servo(4).get('goal_position') == 512


def test_checksum_and_instruction_errors(emu, line):
    good = bytearray(p.encode_instruction(5, p.WRITE, [25, 1]))
    good[-1] ^= 0xFF
    line.send(5, 0, raw=bytes(good))
    assert line.receive().code == p.ERR_CHECKSUM
    assert emu.servo(5).get('led') == 0                            # not executed
    assert line.txrx(5, 0x44).code == p.ERR_INSTRUCTION           # no such instruction
    assert line.txrx(5, p.ACTION).code == p.ERR_INSTRUCTION       # ACTION without REG_WRITE


def test_reg_write_waits_for_broadcast_action(emu, line):
    assert line.txrx(6, p.REG_WRITE, [25, 1]).code == 0
    assert emu.servo(6).get('led') == 0 and line.read(6, 44, 1).params == b'\x01'
    line.send(p.BROADCAST_ID, p.ACTION)
    assert line.receive(timeout=0.05) is None                      # broadcast: no status packet
    assert emu.servo(6).get('led') == 1 and emu.servo(6).get('registered') == 0


def test_sync_write_sets_several_goals_without_reply(emu, line):
    line.send(p.BROADCAST_ID, p.SYNC_WRITE, [30, 2, 1, 0x00, 0x01, 2, 0x58, 0x02, 99, 0, 0])
    assert line.receive(timeout=0.05) is None
    assert emu.servo(1).get('goal_position') == 256 and emu.servo(2).get('goal_position') == 600


def test_bulk_read_is_not_answered_by_ax12(emu, line):
    line.send(p.BROADCAST_ID, p.BULK_READ, [0, 2, 1, 36])
    assert line.receive(timeout=0.05) is None


def test_status_return_level_1_answers_reads_only(emu, line):
    line.send(7, p.WRITE, [16, 1])                  # applied first, so even this write gets no status
    assert line.receive(timeout=0.05) is None
    line.send(7, p.WRITE, [25, 1])
    assert line.receive(timeout=0.05) is None
    assert emu.servo(7).get('led') == 1
    assert line.read(7, 25, 1).params == b'\x01'


def test_return_delay_time_is_honoured(emu, line):
    # factory return delay 250 x 2 us = 0.5 ms; after writing 0 the reply is immediate. Checked on
    # the emulator's log, not by wall-clock round trips: the pty's own latency jitters by tenths of a
    # millisecond on a loaded machine. What is timed is only a lower bound, which cannot flake.
    for _ in range(5):
        assert line.read(8, 36, 2) is not None
    slow = list(emu.log)[-5:]
    assert [e.reply_delay_s for e in slow] == [pytest.approx(0.5e-3)] * 5
    assert all(e.t_reply - e.t >= 0.5e-3 - 1e-9 for e in slow)     # it really waited (on its own clock)
    assert line.txrx(8, p.WRITE, [5, 0]).code == 0
    for _ in range(5):
        assert line.read(8, 36, 2) is not None
    assert [e.reply_delay_s for e in list(emu.log)[-5:]] == [0.0] * 5


def test_overheating_shuts_down_and_recovers_only_after_cooling(emu, line):
    assert line.txrx(9, p.WRITE, [24, 1]).code == 0
    emu.faults.set_temperature(9, 80.0)                              # limit (address 11) is 70
    st = line.read(9, 43, 1)
    assert st.code & p.ERR_OVERHEATING and st.params == bytes([80])
    assert u16(line.read(9, 34, 2).params) == 0                       # alarm shutdown zeroed the torque limit
    line.txrx(9, p.WRITE, [34, 0xFF, 0x03])
    assert u16(line.read(9, 34, 2).params) == 0                       # still hot: shut down again
    emu.faults.set_temperature(9, 40.0)
    assert line.txrx(9, p.WRITE, [34, 0xFF, 0x03]).code == 0
    assert u16(line.read(9, 34, 2).params) == 1023 and emu.servo(9).torque_on


def test_overload_bit_and_load_register(emu, line):
    line.txrx(10, p.WRITE, [24, 1])
    emu.faults.set_overload(10)
    st = line.read(10, 40, 2)
    assert st.code & p.ERR_OVERLOAD
    assert emu.servo(10).get('torque_limit') == 0
    emu.faults.set_overload(10, False)
    assert line.read(10, 40, 2).code == 0


def test_dropped_corrupt_and_missing_servo_faults(emu, line):
    emu.faults.drop_replies(ids=11, count=2)
    assert line.read(11, 36, 2) is None and line.read(11, 36, 2) is None
    assert line.read(11, 36, 2) is not None
    emu.faults.corrupt_replies(ids=11, count=1)
    assert line.read(11, 36, 2).checksum_ok is False
    assert line.read(11, 36, 2).checksum_ok is True
    emu.faults.remove_servo(12)
    assert line.txrx(12, p.PING) is None
    line.send(12, p.WRITE, [25, 1])
    assert emu.servo(12).get('led') == 0                            # a missing servo executes nothing
    emu.faults.restore_servo(12)
    assert line.txrx(12, p.PING) is not None
    assert (emu.faults.dropped, emu.faults.corrupted) == (2, 1)


def test_port_vanishes_and_comes_back_behind_a_stable_link(robot, tmp_path):
    link = tmp_path / 'ttyDXL'
    with BusEmulator(robot, link_path=link) as emu:
        ln = Line(str(link))
        assert ln.txrx(1, p.PING) is not None
        emu.disconnect()
        with pytest.raises(serial.SerialException):
            ln.ser.write(p.encode_instruction(1, p.PING))
            ln.receive()
        ln.ser.close()
        assert not link.exists()
        emu.reconnect()
        ln = Line(str(link))
        assert ln.txrx(1, p.PING) is not None
        ln.close()


def test_ideal_servo_moves_on_the_firmware_grid_at_the_moving_speed(robot):
    be = IdealServoBackend(robot)
    be.speed_ticks_per_s = lambda slot: 1000.0              # 1 tick per 1 ms firmware period
    be.torque(0.0, 0, True)
    be.goals(0.0105, {0: 600})                              # takes effect at the tick at 11 ms
    assert be.sample(0.0109, 0)[0] == 512
    assert be.sample(0.0111, 0)[0] == 513                    # first step at 11 ms
    assert be.sample(0.0205, 0) == (522, 1000.0)
    assert be.sample(1.0, 0) == (600, 0.0)                  # arrived, stops
    be.torque(1.0, 0, False)
    be.goals(1.0, {0: 100})
    assert be.sample(2.0, 0)[0] == 600                      # limp: no motion


def test_emulated_servo_follows_goal_through_the_pty(robot, emu, line):
    """Every position read over the pty is the servo model's position at the emulator's own logged
    arrival time of that READ (no wall-clock sleep decides what the servo should report)."""
    units = 30                                               # moving speed 30 x 0.111 rpm: ~1.3 s to travel
    line.txrx(13, p.WRITE, [32, units, 0])
    line.txrx(13, p.WRITE, [24, 1])
    line.txrx(13, p.WRITE, [30, 0x58, 0x02])                 # goal 600
    reads = []
    deadline = time.monotonic() + 30.0                       # failure bound only
    while not reads or reads[-1] != 600:
        assert time.monotonic() < deadline, f'servo 13 did not reach 600: {reads[-5:]}'
        reads.append(u16(line.read(13, 36, 2).params))
    assert line.read(13, 46, 1).params == b'\x00'            # no longer moving
    log = [e for e in emu.log if e.servo_id == 13]
    t_torque = next(e.t for e in log if e.instruction == p.WRITE and e.address == 24)
    t_goal = next(e.t for e in log if e.instruction == p.WRITE and e.address == 30)
    sampled = [(e.t, u16(e.reply_params)) for e in log if e.instruction == p.READ and e.address == 36]
    assert [v for _, v in sampled] == reads                  # the log holds every read, in order
    slot = next(s.slot for s in emu.servos if s.servo_id == 13)
    model = IdealServoBackend(robot)
    sv = robot.servo
    model.speed_ticks_per_s = lambda _slot: units * p.MOVING_SPEED_UNIT_RPM / 60.0 * sv.ticks_per_range * 360.0 / sv.range_deg
    model.torque(t_torque, slot, True)
    model.goals(t_goal, {slot: 600})
    assert [v for _, v in sampled] == [int(round(model.sample(t, slot)[0])) for t, _ in sampled]
    assert all(b >= a for a, b in zip(reads, reads[1:]))     # it moved towards the goal, never back


class FakeServoBus:
    """A minimal ServoBus: positions follow goals instantly; time advances t_com_s per read."""

    t_com_s = 0.001

    def __init__(self):
        self.t = 100.0
        self.theta = {j: 0.0 for j in ALL_JOINTS}
        self.writes = []

    def now(self):
        return self.t

    def wait_until(self, t):
        self.t = max(self.t, t)

    def sync_write(self, goals_rad):
        self.writes.append((self.t, dict(goals_rad)))
        self.theta.update(goals_rad)
        return self.t

    def read_position(self, joint):
        t = self.t
        self.t += self.t_com_s
        return self.theta[joint], t


def test_servobus_backend_maps_ticks_with_mounting(robot):
    import dataclasses
    joints = tuple(dataclasses.replace(j, direction=-1, offset_ticks=7) if j.joint == 'leg2_femur' else j
                   for j in robot.bus.joints)
    robot2 = dataclasses.replace(robot, bus=dataclasses.replace(robot.bus, joints=joints))
    fake = FakeServoBus()
    be = ServoBusBackend(fake, robot2)
    slot = ALL_JOINTS.index('leg2_femur')
    be.goals(0.5, {slot: 600})
    t_write, goals = fake.writes[-1]
    assert t_write == pytest.approx(be.t0 + 0.5) and be.t0 == pytest.approx(100.001)   # after a warm-up read
    assert goals['leg2_femur'] == pytest.approx(-(600 - 512 - 7) * robot.servo.rad_per_tick)
    tick, _ = be.sample(0.6, slot)
    assert tick == pytest.approx(600)
    assert servo_tick(goals['leg2_femur'], robot.servo, joints[slot]) == pytest.approx(600)


def test_emulator_over_a_servobus_serves_reads_from_it(robot):
    fake = FakeServoBus()
    fake.theta['leg1_tibia'] = 0.3
    with BusEmulator(robot, ServoBusBackend(fake, robot)) as emu:
        ln = Line(emu.port)
        tick = u16(ln.read(3, 36, 2).params)
        assert tick == round(512 + 0.3 / robot.servo.rad_per_tick)
        ln.txrx(3, p.WRITE, [30, 0, 2])
        assert fake.writes[-1][1] == {'leg1_tibia': 0.0}
        ln.close()
    assert math.isfinite(fake.t)


# ----------------------------------------------------------------------------- status level, baud, adapter latency
def _open(port, baud):
    import serial
    return serial.Serial(port, baud, timeout=0.2)


def _ask(ser, pkt, n):
    ser.reset_input_buffer()
    ser.write(pkt)
    return ser.read(n)


def test_status_return_level_follows_the_datasheet(robot):
    with BusEmulator(robot) as emu:
        ser = _open(emu.port, robot.bus.baud_rate)
        ping, read = p.encode_instruction(1, p.PING), p.encode_instruction(1, p.READ, [36, 2])
        write = p.encode_instruction(1, p.WRITE, [25, 1])
        for level, answered in ((0, (True, False, False)), (1, (True, True, False)), (2, (True, True, True))):
            emu.servo(1).set_register('status_return_level', level)
            got = tuple(bool(_ask(ser, pkt, n)) for pkt, n in ((ping, 6), (read, 8), (write, 6)))
            assert got == answered, level
            assert emu.servo(1).get('led') == 1                   # the write is executed either way
            assert emu.log[-1].note == ('' if level == 2 else f'status return level {level}: no status packet')
        ser.close()


def test_servo_at_another_baud_does_not_answer(robot):
    with BusEmulator(robot) as emu:
        emu.servo(1).set_register('baud_rate', 34)                # 57600 baud
        ser = _open(emu.port, robot.bus.baud_rate)
        assert _ask(ser, p.encode_instruction(1, p.PING), 6) == b''
        assert emu.log[-1].note.startswith('baud mismatch')
        assert _ask(ser, p.encode_instruction(2, p.PING), 6) == p.encode_status(2, 0)
        ser.close()
        ser = _open(emu.port, 57600)
        assert _ask(ser, p.encode_instruction(1, p.PING), 6) == p.encode_status(1, 0)
        assert emu.log[-1].tx == p.encode_status(1, 0) and emu.log[-1].rx == p.encode_instruction(1, p.PING)
        ser.close()


@pytest.mark.realtime
def test_reply_latency_holds_replies_back_without_blocking_instructions(robot):
    with BusEmulator(robot) as emu:
        emu.faults.set_reply_latency(0.3)
        ser = _open(emu.port, robot.bus.baud_rate)
        ser.write(p.encode_instruction(1, p.PING))
        assert ser.read(6) == b''                                 # not within 0.2 s
        ser.write(p.encode_instruction(1, p.WRITE, [25, 1]))      # executed on arrival meanwhile
        deadline = time.monotonic() + 5.0
        while emu.servo(1).get('led') != 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert emu.servo(1).get('led') == 1
        ser.timeout = 5.0
        assert ser.read(12) == p.encode_status(1, 0) * 2          # both replies, late, in order
        ser.close()
        ping, write = list(emu.log)[-2:]
        assert ping.t_reply - ping.t >= 0.3 and write.t_reply - write.t >= 0.3     # the log says when they went


@pytest.mark.parametrize('latency_s', [0.0, 0.001])     # behind the held reply, one due at once waits too
def test_a_held_reply_comes_late_and_the_replies_behind_it_wait(robot, latency_s):
    with BusEmulator(robot) as emu:
        emu.faults.set_reply_latency(latency_s)
        emu.faults.hold_replies(0.2, ids=1, count=1)
        ser = _open(emu.port, robot.bus.baud_rate)
        ser.timeout = 5.0
        ser.write(p.encode_instruction(1, p.PING) + p.encode_instruction(2, p.PING))
        assert ser.read(12) == p.encode_status(1, 0) + p.encode_status(2, 0)     # in the order asked
        ser.write(p.encode_instruction(1, p.PING))
        assert ser.read(6) == p.encode_status(1, 0)
        ser.close()
        held, behind = list(emu.log)[-3:-1]
        assert held.t_reply - held.t >= 0.2 and behind.t_reply >= held.t_reply    # on the emulator's clock


def test_a_hold_for_one_address_passes_other_replies_of_the_servo(robot):
    with BusEmulator(robot) as emu:
        emu.faults.hold_replies(0.2, ids=1, count=1, address=0)
        ser = _open(emu.port, robot.bus.baud_rate)
        ser.timeout = 5.0
        for params in ([], [36, 2], [0, 2], [0, 2]):                # PING, READ 36, READ 0 (held), READ 0
            ser.write(p.encode_instruction(1, p.READ if params else p.PING, params))
            assert len(ser.read(6 + (params[1] if params else 0))) == 6 + (params[1] if params else 0)
        ser.close()
        waited = [e.t_reply - e.t >= 0.2 for e in list(emu.log)[-4:]]
        assert waited == [False, False, True, False]                # on the emulator's clock


def test_a_backend_that_is_not_installed_is_named_in_one_error_line(monkeypatch, capsys):
    """bus_emulator finds backends through an entry-point group; without hexapod_sim there is no `sim`."""
    from hexapod_driver.emulator import cli
    monkeypatch.setattr(cli, 'backend_plugins', lambda: {})
    with pytest.raises(SystemExit) as exc:
        cli.main(['--backend', 'sim', '--terrain', 'mockup'])
    assert exc.value.code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if 'error:' in line]
    assert len(err) == 1
    assert "--backend sim: no such backend installed (installed: ideal)" in err[0]
    assert 'hexapod_driver.emulator_backends' in err[0] and 'hexapod_sim' in err[0]


def test_the_reply_record_marks_dropped_and_corrupted_replies(emu, line, tmp_path):
    """What a soak's checks are judged on: a position sent, a read left unanswered, a reply sent with a
    broken checksum (never a position the host can take), each one row."""
    from hexapod_driver.emulator.fault_schedule import CORRUPTED, PRESENT_POSITION, UNANSWERED, ReplyRecorder, load_replies
    sid = emu.robot.bus.joints[0].servo_id
    rec = ReplyRecorder(emu, tmp_path / 'replies.bin', period_s=60.0)
    try:
        emu.log.clear()
        good = line.read(sid, PRESENT_POSITION, 2)
        emu.faults.drop_replies([sid])
        assert line.read(sid, PRESENT_POSITION, 2) is None
        emu.faults.corrupt_replies([sid])
        line.send(sid, p.READ, [PRESENT_POSITION, 2])
        time.sleep(0.1)
    finally:
        rec.close()
    rows = load_replies(tmp_path / 'replies.bin')
    assert rows[:, 1].tolist() == [sid] * 3
    assert rows[:, 2].tolist() == [u16(good.params), UNANSWERED, CORRUPTED]


@pytest.mark.parametrize('args', [
    ['--robot', 'BAD_YAML'],
    ['--robot', 'MISSING/robot.yaml'],
    ['--link', 'MISSING/hexapod_dynamixel'],
    ['--reply-latency-ms', 'nan'],
    ['--corrupt-probability', 'inf'],
    ['--events-out', 'MISSING/faults.jsonl'],
    ['--replies-out', 'MISSING/replies.bin'],
], ids=lambda a: ' '.join(a))
def test_bad_emulator_arguments_are_one_line_before_the_bus_opens(tmp_path, args):
    """The emulator process refuses a bad description, output place or number in one line, before it
    opens a pseudo-terminal (no port line on stdout, nothing created)."""
    import subprocess
    import sys
    (tmp_path / 'broken.yaml').write_text('servo: [unclosed\n')
    args = [a.replace('BAD_YAML', str(tmp_path / 'broken.yaml')).replace('MISSING', str(tmp_path / 'missing'))
            for a in args]
    r = subprocess.run([sys.executable, '-m', 'hexapod_driver.emulator', *args], capture_output=True, text=True,
                       timeout=60, stdin=subprocess.DEVNULL)
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and r.stdout == ''
    assert len(err) == 1 and err[0].startswith('bus_emulator: error: ') and 'Traceback' not in r.stderr, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ['broken.yaml']
