"""Faults that overlap, through the running driver_node process on the emulated bus: two servos
failing at once, faults during start-up and during shutdown, /joint_commands flooding at 1 kHz, and
a ROS clock (use_sim_time) that jumps back or stands still. Each test checks what the node promises:
torque off at exit, no position the servos did not report, diagnostics and logs that say what
happened, no crash or hang.

DDS stays on loopback on a domain of this file's own.
"""
import os
import subprocess
import sys
import time

import pytest

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

import hexapod_testing as testing  # noqa: E402
from hexapod_driver import protocol as p  # noqa: E402
from hexapod_driver.bus import EventKind  # noqa: E402
from hexapod_driver.emulator import BusEmulator  # noqa: E402
from hexapod_model import contract  # noqa: E402
from hexapod_model.servo import servo_tick  # noqa: E402

DOMAIN_ID = 170 + os.getpid() % 10          # 170..179: this file's nodes
PARAMS = ['timeout_margin_ms:=25.0', 'diagnostics_period_s:=0.3', 'timing_period_s:=0.3',
          'read_period_s:=0.005', 'command_timeout_s:=0.0']


OUTPUTS = {}                                # pid -> Output, for the message when a node exits early


def start(port, extra=()):
    args = [sys.executable, '-m', 'hexapod_driver.driver_node', '--ros-args', '-p', f'device:={port}']
    for prm in [*PARAMS, *extra]:
        args += ['-p', prm]
    proc = subprocess.Popen(args, env=testing.node_env(DOMAIN_ID), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    OUTPUTS[proc.pid] = testing.ProcessOutput(proc)
    return proc, OUTPUTS[proc.pid]


class Inbox:
    def __init__(self, node):
        self.states, self.diags = [], []
        self.subs = [node.create_subscription(JointState, contract.JOINT_STATES, self.states.append, 1000),
                     node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self.diags.append, 100)]

    def statuses(self, sid=None):
        out = []
        for m in self.diags:
            for s in m.status:
                if sid is None or s.name.endswith(f'(id {sid})'):
                    out.append(s)
        return out

    def close(self, node):
        for s in self.subs:
            node.destroy_subscription(s)


def wait_for(ex, cond, timeout, proc, what):
    def alive():
        if proc.poll() is not None:
            raise AssertionError(f'driver_node exited ({proc.returncode}) while waiting for {what}:\n'
                                 f'{OUTPUTS[proc.pid].text() if proc.pid in OUTPUTS else ""}')
    testing.spin_until(ex, cond, timeout, what, alive=alive)


def reported_ticks(emu):
    """{servo id: [present positions the servo sent, in order]} from the emulator's log."""
    out = {}
    for e in list(emu.log):
        if e.instruction == p.READ and e.replied and e.address is not None:
            off = 36 - e.address
            if 0 <= off and off + 2 <= len(e.reply_params):
                out.setdefault(e.servo_id, []).append(e.reply_params[off] | e.reply_params[off + 1] << 8)
    return out


def assert_no_invented_positions(robot, emu, states):
    reported = reported_ticks(emu)
    for msg in states:
        mount = robot.bus.by_joint(msg.name[0])
        tick = int(round(float(servo_tick(msg.position[0], robot.servo, mount))))
        assert tick in reported.get(mount.servo_id, []), f'{msg.name[0]}: tick {tick} was never reported'


def test_two_servos_fail_at_once_and_come_back(robot, ros):
    """A coxa silent and a femur overheating at the same moment, then both back: both named on
    /diagnostics and in the log, both recovered (fault_policy recover), nothing invented."""
    node, ex = ros
    with BusEmulator(robot, log_size=200_000) as emu:
        proc, out = start(emu.port, ['fault_policy:=recover', 'reprobe_period_s:=0.2'])
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: len(inbox.states) > 50, 30.0, proc, 'reads')
            emu.faults.remove_servo(4)                       # leg2_coxa
            emu.faults.override_temperature(2, 80.0)          # leg1_femur
            wait_for(ex, lambda: any(not_responding(s) for s in inbox.statuses(4)) and
                     any('overheating' in s.message for s in inbox.statuses(2)), 30.0, proc, 'both faults reported')
            emu.faults.restore_servo(4)
            emu.faults.override_temperature(2, None)
            n = len(inbox.diags)
            wait_for(ex, lambda: any(s.level == b'\x00' for m in inbox.diags[n:] for s in m.status
                                     if s.name.endswith('(id 2)')) and
                     any(s.level == b'\x00' for m in inbox.diags[n:] for s in m.status if s.name.endswith('(id 4)')),
                     30.0, proc, 'both servos OK again')
        finally:
            rc, text = out.finish(proc)
            inbox.close(node)
        assert rc == 0, text
        assert (testing.logged(text, EventKind.READ_FAILED, 'leg2_coxa') or
                testing.logged(text, EventKind.SERVO_MISSING, 'leg2_coxa')), text
        assert testing.logged(text, EventKind.SERVO_ANSWERS, 'leg2_coxa'), text
        assert testing.logged(text, EventKind.FAULT, 'leg1_femur'), text
        assert testing.logged(text, EventKind.RECOVERED, 'leg1_femur'), text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text
        assert_no_invented_positions(robot, emu, inbox.states)


def not_responding(status):
    return any(kv.key == 'responding' and kv.value == 'false' for kv in status.values)


def test_faults_during_startup_are_ridden_out_and_reported(robot, ros):
    """Start-up on a bus that corrupts a tenth of the replies while a servo is overheated: the
    driver starts (start-up retries), says the servo is in alarm, and recovers it once it cools."""
    node, ex = ros
    with BusEmulator(robot, seed=3) as emu:
        rule = emu.faults.corrupt_replies(count=None, probability=0.1)
        emu.faults.override_temperature(7, 80.0)               # leg3_coxa hot before the driver opens the port
        proc, out = start(emu.port, ['fault_policy:=recover'])
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: 'verified and configured' in out.text(), 60.0, proc, 'start-up')
            wait_for(ex, lambda: any('overheating' in s.message for s in inbox.statuses(7)), 30.0, proc,
                     'the overheating on /diagnostics')
            emu.faults.cancel(rule)
            emu.faults.override_temperature(7, None)
            wait_for(ex, lambda: 'leg3_coxa (id 7) recovered' in out.text(), 30.0, proc, 'the recovery')
        finally:
            rc, text = out.finish(proc)
            inbox.close(node)
        assert rc == 0, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text


def test_port_back_at_shutdown_gets_torque_off(robot, ros, tmp_path):
    """The adapter was unplugged and is back when Ctrl-C comes, before the driver's own reopen
    (reconnect_period_s long): the exit reopens the port and turns torque off, and says so."""
    node, ex = ros
    with BusEmulator(robot, link_path=tmp_path / 'ttyDXL') as emu:
        proc, out = start(emu.port, ['reconnect_period_s:=30.0'])
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: len(inbox.states) > 20, 30.0, proc, 'reads')
            emu.disconnect()
            wait_for(ex, lambda: 'port lost' in out.text(), 30.0, proc, 'the port loss in the log')
            wait_for(ex, lambda: any('port lost' in s.message for s in inbox.statuses()), 30.0, proc,
                     'the port loss on /diagnostics')
            emu.reconnect()
        finally:
            rc, text = out.finish(proc)
            inbox.close(node)
        assert rc == 0, text
        assert 'torque off on all servos (read back)' in text, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text


def test_servo_silent_at_shutdown_is_named_and_the_rest_are_off(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start(emu.port)
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: len(inbox.states) > 20, 30.0, proc, 'reads')
            emu.faults.remove_servo(5)                       # leg2_femur: gone as Ctrl-C comes
        finally:
            rc, text = out.finish(proc)
            inbox.close(node)
        assert rc == 0, text
        assert 'torque state unknown for leg2_femur' in text and 'confirmed for the other 17' in text, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos if s.servo_id != 5), text


def test_joint_commands_flood_at_1khz(robot, ros):
    """/joint_commands at 1 kHz for 3 s: the driver keeps reading, the goals reach the servo, a clean exit."""
    node, ex = ros
    with BusEmulator(robot, log_size=200_000) as emu:
        proc, out = start(emu.port)
        inbox = Inbox(node)
        pub = node.create_publisher(JointState, contract.JOINT_COMMANDS, 10)
        try:
            wait_for(ex, lambda: len(inbox.states) > 20, 30.0, proc, 'reads')
            n0 = len(inbox.states)
            t_end, k = time.monotonic() + 3.0, 0
            while time.monotonic() < t_end:
                msg = JointState()
                msg.header.stamp = node.get_clock().now().to_msg()
                msg.name, msg.position = ['leg1_coxa'], [0.2 * ((k // 100) % 2)]
                pub.publish(msg)
                k += 1
                ex.spin_once(timeout_sec=0.001)
            wait_for(ex, lambda: len(inbox.states) > n0 + 100, 30.0, proc, 'reads during and after the flood')
            goal = round(512 + 0.2 / robot.servo.rad_per_tick) if (k - 1) // 100 % 2 else 512
            wait_for(ex, lambda: emu.servo(1).get('goal_position') == goal, 10.0, proc, 'the last goal')
        finally:
            rc, text = out.finish(proc)
            inbox.close(node)
            node.destroy_publisher(pub)
        assert rc == 0, text
        assert 'Traceback' not in text, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text
        assert_no_invented_positions(robot, emu, inbox.states)


def _publish_clock(node, pub, t):
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = int(t), int((t % 1) * 1e9)
    pub.publish(msg)


def test_sim_clock_jumping_back_does_not_stall_the_reads(robot, ros):
    """use_sim_time: the clock runs, is reset to near zero (a sim restarted), runs on. The reads go
    on after the jump, the log names it, and the node exits cleanly."""
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start(emu.port, ['use_sim_time:=true', 'watchdog_timeout_s:=0.0'])
        inbox = Inbox(node)
        pub = node.create_publisher(Clock, contract.CLOCK, 10)
        t = [1000.0]

        def tick_until(cond, what):
            def step():
                t[0] += 0.01
                _publish_clock(node, pub, t[0])
                return cond()
            wait_for(ex, step, 60.0, proc, what)
        try:
            tick_until(lambda: 'verified and configured' in out.text() and len(inbox.states) > 20, 'reads on sim time')
            t[0] = 5.0                                       # the sim restarted
            n0 = len(inbox.states)
            tick_until(lambda: len(inbox.states) > n0 + 20, 'reads after the clock jumped back')
            assert all(contract.stamp_seconds(m.header.stamp) < 100.0 for m in inbox.states[-10:])   # on the new time
        finally:
            rc, text = out.finish(proc)
            inbox.close(node)
            node.destroy_publisher(pub)
        assert rc == 0, text
        assert testing.logged(text, EventKind.CLOCK_JUMPED), text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text


def test_paused_sim_clock_is_said_and_exit_is_prompt(robot, ros):
    """use_sim_time with a clock that stands still: the driver says the clock is not advancing
    (reads wait for it) and still exits at once on Ctrl-C with torque off."""
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start(emu.port, ['use_sim_time:=true'])
        inbox = Inbox(node)
        pub = node.create_publisher(Clock, contract.CLOCK, 10)
        try:
            def paused():
                _publish_clock(node, pub, 500.0)             # published again and again, never advancing
                return bool(testing.logged(out.text(), EventKind.CLOCK_PAUSED))
            wait_for(ex, paused, 60.0, proc, 'the paused clock in the log')
        finally:
            t0 = time.monotonic()
            rc, text = out.finish(proc)                      # also when the wait failed: no node left behind
            took = time.monotonic() - t0
            inbox.close(node)
            node.destroy_publisher(pub)
        assert rc == 0, text
        assert '<<killed' not in text, text
        assert all(s.get('torque_enable') == 0 for s in emu.servos), text
        print(f'exit took {took:.2f} s after SIGINT')
