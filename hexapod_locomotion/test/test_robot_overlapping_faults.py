"""The composed robot (driver + model + locomotion in one process) on the emulated bus, with inputs
and faults that overlap: /cmd_vel and /joint_commands flooding at 1 kHz (valid and NaN), a fault
during start-up, and the port lost as Ctrl-C comes. Through the running process: it keeps walking,
says what happened once (not a thousand times a second), never crashes, and turns torque off at exit.
"""
import os
import subprocess
import sys
import time

import pytest

rclpy = pytest.importorskip('rclpy')
from geometry_msgs.msg import Twist  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

import hexapod_testing as testing  # noqa: E402
from hexapod_driver.bus import EventKind  # noqa: E402
from hexapod_driver.emulator import BusEmulator  # noqa: E402
from hexapod_model import contract  # noqa: E402
from hexapod_model.description import load_robot  # noqa: E402

DOMAIN_ID = 175 + os.getpid() % 5          # 175..179


class Output(testing.ProcessOutput):
    """The node's output (testing.ProcessOutput) and what these tests ask of it."""

    def count(self, needle):
        return sum(needle in ln for ln in list(self.lines))



def installed(pkg, exe):
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(pkg), 'lib', pkg, exe)


def start_robot(port, extra=()):
    args = [sys.executable, installed('hexapod_locomotion', 'robot'), '--ros-args', '-p', 'hardware:=driver',
            '-p', f'device:={port}', '-p', 'timeout_margin_ms:=25.0']
    for prm in extra:
        args += ['-p', prm]
    proc = subprocess.Popen(args, env=testing.node_env(DOMAIN_ID), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    return proc, Output(proc)


@pytest.fixture(scope='module')
def ros():
    with testing.ros_probe('robot_overlapping_faults_test', DOMAIN_ID) as probe:
        yield probe


def wait_for(ex, cond, timeout, proc, out, what):
    def alive():
        if proc.poll() is not None:
            raise AssertionError(f'robot exited ({proc.returncode}) while waiting for {what}:\n{out.text()}')
    testing.spin_until(ex, cond, timeout, what, alive=alive)


def twist(vx=0.0, wz=0.0):
    m = Twist()
    m.linear.x, m.angular.z = vx, wz
    return m


@pytest.mark.realtime
def test_cmd_vel_and_joint_commands_flood_at_1khz(ros):
    node, ex = ros
    with BusEmulator(load_robot()) as emu:
        proc, out = start_robot(emu.port)
        cmd = node.create_publisher(Twist, contract.CMD_VEL, 10)
        jc = node.create_publisher(JointState, contract.JOINT_COMMANDS, 10)
        try:
            wait_for(ex, lambda: (cmd.publish(twist(0.04)) or out.count('phase ') >= 2), 120.0, proc, out,
                     'walking')
            phases0 = out.count('phase ')
            t_end, k = time.monotonic() + 3.0, 0
            while time.monotonic() < t_end:                  # valid commands that change, and NaN ones
                cmd.publish(twist(float('nan')) if k % 2 else twist(0.02 + 0.02 * (k // 500 % 2), 0.1))
                js = JointState()
                js.name, js.position = ['leg1_coxa'], [0.5]       # not the controller's: the topic is not taken
                jc.publish(js)
                k += 1
                ex.spin_once(timeout_sec=0.001)
            wait_for(ex, lambda: (cmd.publish(twist(0.04)) or out.count('phase ') >= phases0 + 3), 120.0, proc, out,
                     'walking on after the flood')
        finally:
            rc, text = out.finish(proc)
            node.destroy_publisher(cmd)
            node.destroy_publisher(jc)
        assert rc == 0, text
        rejected = text.count('/cmd_vel rejected')
        assert 1 <= rejected <= 10, f'{rejected} rejection lines for a 3 s NaN flood:\n{text[-3000:]}'
        assert 'not finite' in text
        assert 'Traceback' not in text, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text


@pytest.mark.realtime
def test_fault_at_startup_then_port_lost_at_ctrl_c(ros, tmp_path):
    """A servo silent while the robot starts: start-up fails naming it, torque off on the others,
    exit 1. Then a start on a bus that drops a tenth of the replies; while walking, the adapter is
    unplugged and back as Ctrl-C comes: torque off, exit 0."""
    node, ex = ros
    robot = load_robot()
    with BusEmulator(robot, link_path=tmp_path / 'ttyDXL', seed=5) as emu:
        emu.faults.remove_servo(8)
        proc, out = start_robot(emu.port)
        try:
            proc.wait(timeout=120.0)
        finally:
            rc, text = out.finish(proc)                     # stopped even when it did not exit by itself
        assert rc == 1, text
        assert 'id 8' in text and 'Traceback' not in text, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos if s.servo_id != 8), text
        emu.faults.restore_servo(8)

        rule = emu.faults.drop_replies(count=None, probability=0.1)
        proc, out = start_robot(emu.port, ['reconnect_period_s:=30.0'])
        cmd = node.create_publisher(Twist, contract.CMD_VEL, 10)
        try:
            wait_for(ex, lambda: (cmd.publish(twist(0.04)) or out.count('phase ') >= 2), 120.0, proc, out,
                     'walking on a lossy bus')
            emu.faults.cancel(rule)
            emu.disconnect()
            wait_for(ex, lambda: testing.logged(out.text(), EventKind.PORT_LOST), 30.0, proc, out, 'the port loss in the log')
            emu.reconnect()
        finally:
            rc, text = out.finish(proc)
            node.destroy_publisher(cmd)
        assert 'Traceback' not in text, text
        assert 'torque off on all servos (read back)' in text, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text
