"""The actual ROS driver_node process against the emulated bus: topics, commands, schedule,
diagnostics, timing, emergency stop, torque off at shutdown, start-up failure.

DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on a domain of its own.
"""
import math
import os
import signal
import subprocess
import sys
import time

import pytest

rclpy = pytest.importorskip('rclpy')
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

import hexapod_testing as testing  # noqa: E402
from hexapod_driver.bus import EventKind  # noqa: E402
from hexapod_driver.emulator import BusEmulator  # noqa: E402
from hexapod_model import contract  # noqa: E402
from hexapod_model.description import ALL_JOINTS  # noqa: E402
from hexapod_msgs.msg import BusTiming, ReadSchedule, ServoDiagnostics  # noqa: E402
from hexapod_msgs.srv import SetReadSchedule  # noqa: E402

DOMAIN_ID = 20 + os.getpid() % 20          # 20..39: this package's node tests
PARAMS = ['timeout_margin_ms:=25.0', 'diagnostics_period_s:=0.3', 'timing_period_s:=0.3',
          'read_period_s:=0.005', 'command_timeout_s:=0.0']   # 200 reads/s: a loaded CI keeps up


def node_env():
    return testing.node_env(DOMAIN_ID)


def start_node(port, extra=()):
    args = [sys.executable, '-m', 'hexapod_driver.driver_node', '--ros-args', '-p', f'device:={port}']
    for prm in [*PARAMS, *extra]:
        args += ['-p', prm]
    return subprocess.Popen(args, env=node_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop_node(proc):
    return testing.stop_process(proc, timeout_s=10.0)


class Inbox:
    def __init__(self, node):
        self.states, self.diag, self.timing = [], [], []
        self.subs = [node.create_subscription(JointState, contract.JOINT_STATES, self.states.append, 500),
                     node.create_subscription(ServoDiagnostics, contract.SERVO_DIAGNOSTICS, self.diag.append, 10),
                     node.create_subscription(BusTiming, contract.BUS_TIMING, self.timing.append, 10)]

    def close(self, node):
        for s in self.subs:
            node.destroy_subscription(s)


def spin_until(ex, cond, timeout, proc=None, what=''):
    def alive():
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f'driver_node exited ({proc.returncode}) while waiting for {what}:\n'
                                 f'{proc.communicate()[0]}')
    testing.spin_until(ex, cond, timeout, what or 'a condition', alive=alive)


def call_idempotent(ex, client, request, timeout, proc, what):
    """Call a service with an idempotent request and return the response. A request sent right
    after discovery can lose its response (the server has not yet matched the client's response
    reader), so it is asked up to three times."""
    for attempt in range(3):
        fut = client.call_async(request)
        try:
            spin_until(ex, fut.done, timeout, proc, what)
            return fut.result()
        except AssertionError:
            if attempt == 2:
                raise


def command(node, pub, names, positions):
    msg = JointState()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.name, msg.position = list(names), list(positions)
    pub.publish(msg)


def test_driver_node_serves_the_topic_contract(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc = start_node(emu.port)
        inbox = Inbox(node)
        cmd_pub = node.create_publisher(JointState, contract.JOINT_COMMANDS, 10)
        sched_pub = node.create_publisher(ReadSchedule, contract.READ_SCHEDULE, 10)
        try:
            spin_until(ex, lambda: len(inbox.states) >= 40, 30.0, proc, '/joint_states')
            # one joint per message, default schedule = all 18 in order, stamps increasing
            names = [m.name[0] for m in inbox.states]
            assert all(len(m.name) == len(m.position) == 1 for m in inbox.states)
            idx = [ALL_JOINTS.index(n) for n in names]
            assert all((b - a) % 18 == 1 for a, b in zip(idx, idx[1:]))
            stamps = [contract.stamp_seconds(m.header.stamp) for m in inbox.states]
            assert all(b > a for a, b in zip(stamps, stamps[1:]))
            assert abs(stamps[-1] - time.time()) < 5.0                  # ROS (system) time

            # a valid command reaches the servo; a NaN command does not
            expected = round(512 + 0.3 / robot.servo.rad_per_tick)
            spin_until(ex, lambda: (command(node, cmd_pub, ['leg1_coxa'], [0.3]) or
                                    emu.servo(1).get('goal_position') == expected), 10.0, proc, 'goal on servo 1')
            command(node, cmd_pub, ['leg2_coxa'], [math.nan])
            command(node, cmd_pub, ['leg9_coxa'], [0.1])
            # a valid command sent after them: once it is on servo 1, the two before it were handled
            # (one subscription, in order) - no fixed wait decides that nothing else arrived
            after = round(512 + 0.2 / robot.servo.rad_per_tick)
            command(node, cmd_pub, ['leg1_coxa'], [0.2])
            spin_until(ex, lambda: emu.servo(1).get('goal_position') == after, 10.0, proc, 'the later goal on servo 1')
            assert emu.servo(4).get('goal_position') == 512

            # the schedule: only the femurs of legs 1 and 2, alternating
            msg = ReadSchedule()
            msg.joint_names = ['leg1_femur', 'leg2_femur']
            sched_pub.publish(msg)
            spin_until(ex, lambda: inbox.states[-1].name[0] in msg.joint_names, 10.0, proc, 'schedule')
            n0 = len(inbox.states)
            spin_until(ex, lambda: len(inbox.states) >= n0 + 20, 10.0, proc, 'scheduled reads')
            tail = [m.name[0] for m in inbox.states[n0:]]
            assert set(tail) == {'leg1_femur', 'leg2_femur'}
            assert all(a != b for a, b in zip(tail, tail[1:]))

            # the same through the service: refused with the bad name, or applied before the answer
            client = node.create_client(SetReadSchedule, contract.SET_READ_SCHEDULE)
            spin_until(ex, client.service_is_ready, 10.0, proc, contract.SET_READ_SCHEDULE)

            def call(names):
                return call_idempotent(ex, client, SetReadSchedule.Request(joint_names=names), 5.0, proc,
                                       'set_read_schedule response')

            bad = call(['leg3_femur', 'leg3_knee'])
            assert not bad.success and 'leg3_knee' in bad.message
            assert call(['leg3_tibia']).success
            n0 = len(inbox.states)
            spin_until(ex, lambda: len(inbox.states) >= n0 + 10, 10.0, proc, 'reads after the service call')
            assert {m.name[0] for m in inbox.states[n0 + 2:]} == {'leg3_tibia'}   # (2 may have been in flight)
            node.destroy_client(client)

            spin_until(ex, lambda: inbox.diag and inbox.timing and inbox.timing[-1].reads > 0, 10.0, proc,
                       'diagnostics and timing')
            d = inbox.diag[-1]
            assert [s.joint_name for s in d.servos] == list(ALL_JOINTS)
            assert all(s.responding and s.torque_enabled and s.voltage_v == pytest.approx(12.0) for s in d.servos)
            tm = inbox.timing[-1]
            assert 0 < tm.t_com_mean_s <= tm.t_com_p99_s <= tm.t_com_max_s < 1.0
            assert all(s.get('torque_enable') == 1 for s in emu.servos)
        finally:
            rc, out = stop_node(proc)
            inbox.close(node)
            node.destroy_publisher(cmd_pub)
            node.destroy_publisher(sched_pub)
        assert rc == 0, out
        assert all(s.get('torque_enable') == 0 for s in emu.servos), out     # torque off at shutdown
        assert 'torque off on all servos' in out


def test_servo_mounting_comes_from_a_description_overlay(robot, ros, tmp_path):
    """One source of truth: the driver has no mounting parameters; an overlay of the description
    (as model and sim load it) mirrors and offsets a joint on the bus."""
    overlay = tmp_path / 'my_robot.yaml'
    overlay.write_text('bus:\n  joints:\n    leg1_coxa: {direction: -1, offset_ticks: 10}\n')
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc = start_node(emu.port, [f'robot_overlays:=[{overlay}]'])
        cmd_pub = node.create_publisher(JointState, contract.JOINT_COMMANDS, 10)
        expected = round(512 - 0.3 / robot.servo.rad_per_tick + 10)
        try:
            spin_until(ex, lambda: (command(node, cmd_pub, ['leg1_coxa'], [0.3]) or
                                    emu.servo(1).get('goal_position') == expected), 30.0, proc, 'mirrored goal')
        finally:
            rc, out = stop_node(proc)
            node.destroy_publisher(cmd_pub)
        assert rc == 0, out


def test_emergency_stop_service(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc = start_node(emu.port)
        client = node.create_client(Trigger, contract.EMERGENCY_STOP)
        try:
            spin_until(ex, lambda: client.service_is_ready(), 30.0, proc, '/emergency_stop')
            assert all(s.get('torque_enable') == 1 for s in emu.servos)
            res = call_idempotent(ex, client, Trigger.Request(), 10.0, proc, 'emergency stop response')
            assert res.success, res.message
            assert all(s.get('torque_enable') == 0 for s in emu.servos)
        finally:
            rc, out = stop_node(proc)
            node.destroy_client(client)
        assert rc == 0, out


def test_missing_servo_fails_startup_naming_it(robot):
    with BusEmulator(robot, absent_ids=(17,)) as emu:
        proc = start_node(emu.port)
        try:
            out, _ = proc.communicate(timeout=30.0)              # exits by itself
        finally:
            if proc.poll() is None:
                proc.kill()
        rc = proc.returncode
    assert rc == 1
    assert 'no answer from leg6_femur (id 17)' in out


# ----------------------------------------------------------------------------- faults through the node

from hexapod_driver import protocol as p  # noqa: E402
from hexapod_model.servo import servo_tick  # noqa: E402


def start_node_env(port, extra=(), env_extra=None):
    args = [sys.executable, '-m', 'hexapod_driver.driver_node', '--ros-args', '-p', f'device:={port}']
    for prm in [*PARAMS, *extra]:
        args += ['-p', prm]
    proc = subprocess.Popen(args, env={**node_env(), **(env_extra or {})}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    return proc, testing.ProcessOutput(proc)


def wait_for(ex, cond, timeout, proc, what):
    spin_until(ex, cond, timeout, None, what)
    assert proc.poll() is None or what.startswith('exit'), f'driver_node exited while waiting for {what}'


def comes_up_and_reads(node, ex, port, timeout=30.0) -> tuple[int, str]:
    """Start the node on ``port``, wait until it has published 20 states, stop it: -> (exit code, its log)."""
    proc, out = start_node_env(port)
    inbox = Inbox(node)
    try:
        wait_for(ex, lambda: len(inbox.states) > 20, timeout, proc, 'reads')
    finally:
        rc, text = out.finish(proc, timeout=15.0)
        inbox.close(node)
    return rc, text


def sample_tick(robot, msg):
    return int(round(float(servo_tick(msg.position[0], robot.servo, robot.bus.by_joint(msg.name[0])))))


def request_of(emu, sid, stamp):
    """The emulator's log entry of the READ a sample stamped ``stamp`` answers: the first READ of that
    servo to arrive at or after the stamp (the driver stamps just before writing; the request before
    it arrived before that write)."""
    for e in list(emu.log):
        if e.servo_id == sid and e.instruction == p.READ and e.address is not None and e.wall >= stamp:
            return e
    return None


def test_noisy_bus_keeps_reading_and_never_invents_a_position(robot, ros):
    node, ex = ros
    with BusEmulator(robot, seed=11) as emu:
        emu.faults.drop_replies(count=None, probability=0.1)
        emu.faults.corrupt_replies(count=None, probability=0.1)
        proc, out = start_node_env(emu.port)                    # start-up itself on the noisy bus
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: len(inbox.states) >= 600 and len(inbox.diag) >= 3, 90.0, proc,
                     'reads on the noisy bus')
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            inbox.close(node)
        log = list(emu.log)
    assert rc == 0, text
    assert 'Logger severity' not in text and 'Traceback' not in text, text
    clean = [e for e in log if e.instruction == p.READ and e.replied and len(e.tx) >= 6
             and p.checksum(e.tx[2:-1]) == e.tx[-1]]
    bad = [e for e in log if e.instruction == p.READ and e.address is not None and e.servo_id != p.BROADCAST_ID
           and e not in clean]
    assert bad, 'the fault injection did nothing'
    # every published position is the answer the servo gave to exactly that request
    by_id = {bj.joint: bj.servo_id for bj in robot.bus.joints}
    for m in inbox.states[::7]:
        stamp = contract.stamp_seconds(m.header.stamp)
        e = request_of(emu, by_id[m.name[0]], stamp)
        assert e is not None and e in clean, (m, e)
        assert sample_tick(robot, m) == e.reply_params[0] | e.reply_params[1] << 8
    # the position reads kept going through the whole run: no second of emulator time without reads
    reads = sorted(e.t for e in log if e.instruction == p.READ and e.address == 36)
    t0, t1 = reads[0] + 1.0, reads[-1]
    secs = {int(t - t0) for t in reads if t0 <= t < t1}
    assert set(range(int(t1 - t0))) <= secs, 'a second without position reads'
    # failures are reported per joint (diagnostics) and counted (timing)
    d = inbox.diag[-1]
    reported = [s for s in d.servos if 'without a valid reply' in s.message]
    assert reported and sum(tm.failed_reads for tm in inbox.timing) > 0
    assert testing.logged(text, EventKind.READ_FAILED), text


def test_overheating_servo_is_limp_others_commandable_and_recover_restores(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start_node_env(emu.port, ['fault_policy:=recover'])
        inbox = Inbox(node)
        cmd_pub = node.create_publisher(JointState, contract.JOINT_COMMANDS, 10)
        try:
            wait_for(ex, lambda: inbox.diag, 30.0, proc, 'first diagnostics')
            emu.faults.set_temperature(6, 85.0)                     # leg2_tibia
            assert emu.servo(6).get('torque_limit') == 0            # the servo's own alarm shutdown

            def tibia():
                return next(s for s in inbox.diag[-1].servos if s.joint_name == 'leg2_tibia')
            wait_for(ex, lambda: tibia().error_bits & p.ERR_OVERHEATING and 'torque limit 0 (limp)' in tibia().message,
                     20.0, proc, 'overheating on diagnostics')
            assert not tibia().torque_enabled                       # limp is not "holding"
            others = [j for j in ALL_JOINTS if j != 'leg2_tibia']
            ids = {bj.joint: bj.servo_id for bj in robot.bus.joints}
            goal = round(512 + 0.1 / robot.servo.rad_per_tick)

            def reached():
                return sum(emu.servo(ids[j]).get('goal_position') != 512 for j in others) == len(others)
            wait_for(ex, lambda: command(node, cmd_pub, others, [0.1] * len(others)) or reached(), 20.0, proc,
                     'the other 17 joints commanded')
            assert any(e.instruction == p.SYNC_WRITE for e in emu.log)
            assert goal in {emu.servo(ids[j]).get('goal_position') for j in others}
            assert emu.servo(6).get('torque_limit') == 0
            emu.faults.set_temperature(6, 40.0)                     # alarm clears
            wait_for(ex, lambda: emu.servo(6).get('torque_limit') == 1023, 20.0, proc, 'torque limit restored')
            assert any(e.servo_id == 6 and e.instruction == p.WRITE and e.address == 34 and e.data == b'\xff\x03'
                       and e.replied for e in emu.log)
            assert emu.servo(6).torque_on
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            inbox.close(node)
            node.destroy_publisher(cmd_pub)
    assert rc == 0, text
    assert 'Logger severity' not in text and 'Traceback' not in text, text
    assert testing.logged(text, EventKind.RECOVERED, 'leg2_tibia'), text


def test_diagnostics_topic_reports_every_servo_and_the_bus(robot, ros):
    """/diagnostics (diagnostic_msgs/DiagnosticArray) from the real process: 18 servos and the bus,
    all OK; an overheating servo turns ERROR with its temperature, error bits and torque limit
    while the others and the bus stay OK."""
    from diagnostic_msgs.msg import DiagnosticArray
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start_node_env(emu.port, ['fault_policy:=recover'])
        got = []
        sub = node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, got.append, 10)
        try:
            wait_for(ex, lambda: got and len(got[-1].status) == 19 and got[-1].status[1].values[2].value != 'unknown'
                     and all(s.level == b'\x00' for s in got[-1].status[1:]), 30.0, proc, 'servos OK on /diagnostics')
            bus = got[-1].status[0]
            values = {kv.key: kv.value for kv in bus.values}
            # the bus may WARN on a loaded machine (emulated reads slower than the model's T_com), never ERROR
            assert bus.name == 'hexapod_driver: bus' and bus.level in (b'\x00', b'\x01'), bus.message
            assert float(values['read_rate_hz']) > 20 and float(values['t_com_mean_ms']) > 0
            names = [s.name for s in got[-1].status[1:]]
            assert names == [f'hexapod_driver: servo {j} (id {i})' for j, i in
                             ((bj.joint, bj.servo_id) for bj in robot.bus.joints)]
            emu.faults.set_temperature(6, 85.0)                     # leg2_tibia

            def tibia():
                return next(s for s in got[-1].status if 'leg2_tibia' in s.name)
            wait_for(ex, lambda: tibia().level == b'\x02', 20.0, proc, 'leg2_tibia ERROR on /diagnostics')
            v = {kv.key: kv.value for kv in tibia().values}
            assert v['temperature_c'] == '85.0' and 'overheating' in v['error_bits'] and v['torque_limit'] == '0%'
            assert 'overheating error' in tibia().message and tibia().hardware_id == 'dynamixel id 6'
            assert [s.level for s in got[-1].status[1:] if 'leg2_tibia' not in s.name] == [b'\x00'] * 17
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            node.destroy_subscription(sub)
    assert rc == 0, text


def test_emergency_stop_twice_with_different_outcomes(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start_node_env(emu.port)
        client = node.create_client(Trigger, contract.EMERGENCY_STOP)
        try:
            wait_for(ex, client.service_is_ready, 30.0, proc, '/emergency_stop')
            first = call_idempotent(ex, client, Trigger.Request(), 10.0, proc, 'first emergency stop')
            assert first.success and 'torque off on all servos (read back)' in first.message
            for s in emu.servos:
                emu.faults.remove_servo(s.servo_id)                 # nobody answers any more
            second = call_idempotent(ex, client, Trigger.Request(), 30.0, proc, 'second emergency stop')
            assert not second.success and 'torque state unknown' in second.message
            assert proc.poll() is None                              # the node lives on
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            node.destroy_client(client)
    assert rc == 0, text
    assert 'Logger severity' not in text and 'Traceback' not in text, text


def test_port_lost_then_sigterm_makes_no_false_torque_off_claim(robot, ros, tmp_path):
    node, ex = ros
    with BusEmulator(robot, link_path=tmp_path / 'ttyDXL') as emu:
        proc, out = start_node_env(emu.port, ['reconnect_period_s:=0.1'])
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: len(inbox.states) > 20, 30.0, proc, 'reads')
            emu.disconnect()
            wait_for(ex, lambda: testing.logged(out.text(), EventKind.RECONNECT_FAILED), 30.0, proc, 'a failed reconnect')
            wait_for(ex, lambda: 'watchdog: no bus transaction completed' in out.text(), 30.0, proc, 'the watchdog')
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            inbox.close(node)
    assert rc == 0, text
    assert 'torque state unknown: port lost' in text and 'torque off on all servos' not in text, text
    assert 'Traceback' not in text, text


def test_servos_at_another_baud_get_an_actionable_error(robot):
    with BusEmulator(robot) as emu:
        for s in emu.servos:
            s.set_register('baud_rate', 34)                          # 57600 baud
        proc, out = start_node_env(emu.port, ['startup_attempts:=1'])
        proc.wait(timeout=60)
        rc, text = out.finish(proc, timeout=15.0)
    assert rc == 1
    assert 'no servo answers at 1000000 baud' in text and 'servo_tool' in text and '--baud' in text
    assert 'Traceback' not in text


def test_status_return_level_1_is_set_to_2_at_startup(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        for s in emu.servos:
            s.set_register('status_return_level', 1)
        rc, text = comes_up_and_reads(node, ex, emu.port)
    assert rc == 0, text
    assert all(s.get('status_return_level') == 2 for s in emu.servos)
    assert len(testing.logged(text, EventKind.STATUS_RETURN_LEVEL_SET)) == 18, text
    assert all(s.get('torque_enable') == 0 for s in emu.servos)


def test_help_does_not_open_the_device():
    r = subprocess.run([sys.executable, '-m', 'hexapod_driver.driver_node', '--help'], env=node_env(),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and 'watchdog_timeout_s' in r.stdout and 'fault_policy' in r.stdout
    assert '/dev/hexapod_dynamixel' in r.stdout and 'cannot open' not in r.stdout + r.stderr
    for gone in ('servo_ids', 'directions', 'offsets_ticks', 'baud_rate', 'compliance_slope'):   # the description's
        assert f'  {gone} (default' not in r.stdout
