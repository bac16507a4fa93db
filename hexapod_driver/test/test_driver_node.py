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
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from hexapod_model import contract  # noqa: E402
from hexapod_model.description import ALL_JOINTS, load_robot  # noqa: E402
from hexapod_msgs.msg import BusTiming, ReadSchedule, ServoDiagnostics  # noqa: E402
from hexapod_msgs.srv import SetReadSchedule  # noqa: E402
from hexapod_driver.emulator import BusEmulator  # noqa: E402

DOMAIN_ID = 20 + os.getpid() % 20          # 20..39: this package's node tests
PARAMS = ['timeout_margin_ms:=25.0', 'diagnostics_period_s:=0.3', 'timing_period_s:=0.3',
          'read_period_s:=0.005', 'command_timeout_s:=0.0']   # 200 reads/s: a loaded CI keeps up


def node_env():
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    return env


def start_node(port, extra=()):
    args = [sys.executable, '-m', 'hexapod_driver.driver_node', '--ros-args', '-p', f'device:={port}']
    for prm in [*PARAMS, *extra]:
        args += ['-p', prm]
    return subprocess.Popen(args, env=node_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop_node(proc, timeout=10.0):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return proc.returncode, out


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def ros():
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    node = rclpy.create_node('driver_node_test', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    yield node, ex
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


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
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.05)
        if cond():
            return
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f'driver_node exited ({proc.returncode}) while waiting for {what}:\n'
                                 f'{proc.communicate()[0]}')
    raise AssertionError(f'timed out waiting for {what}')


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
            stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in inbox.states]
            assert all(b > a for a, b in zip(stamps, stamps[1:]))
            assert abs(stamps[-1] - time.time()) < 5.0                  # ROS (system) time

            # a valid command reaches the servo; a NaN command does not
            expected = round(512 + 0.3 / robot.servo.rad_per_tick)
            spin_until(ex, lambda: (command(node, cmd_pub, ['leg1_coxa'], [0.3]) or
                                    emu.servo(1).get('goal_position') == expected), 10.0, proc, 'goal on servo 1')
            command(node, cmd_pub, ['leg2_coxa'], [math.nan])
            command(node, cmd_pub, ['leg9_coxa'], [0.1])
            t_end = time.monotonic() + 0.5
            spin_until(ex, lambda: time.monotonic() > t_end, 2.0, proc, 'time to pass')
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
