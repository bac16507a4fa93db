"""The driver_node process as a managed (lifecycle) node against the emulated bus: each transition
through its lifecycle services and what the servos and the topics show after it (while inactive, no
data topic carries a message and no command reaches the bus; /diagnostics goes on); and a fault
injected through the bus the node is built from (``main(bus_factory=...)``).

DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on a domain of its own.
"""
import math
import os
import subprocess
import sys
import time

import pytest

rclpy = pytest.importorskip('rclpy')
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from lifecycle_msgs.msg import Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

import hexapod_testing as testing  # noqa: E402
from hexapod_driver import protocol as p  # noqa: E402
from hexapod_driver.config import NODE  # noqa: E402
from hexapod_driver.emulator import BusEmulator  # noqa: E402
from hexapod_model import contract  # noqa: E402
from hexapod_msgs.msg import BusTiming, ServoDiagnostics  # noqa: E402

DOMAIN_ID = 20 + os.getpid() % 20          # 20..39: this package's node tests
PARAMS = ['timeout_margin_ms:=25.0', 'diagnostics_period_s:=0.3', 'timing_period_s:=0.3',
          'read_period_s:=0.005', 'command_timeout_s:=0.0']

# A driver executable whose bus raises inside its loop once the file named by its first argument
# exists: the fault comes from the objects the node is built from, in the real process.
CRASHING_DRIVER = '''
import os
import sys

from hexapod_driver import driver_node
from hexapod_driver.bus import DynamixelBus

TRIGGER = sys.argv.pop(1)


class CrashingBus(DynamixelBus):
    def step(self):
        if os.path.exists(TRIGGER):
            raise RuntimeError('exception forced inside the bus loop')
        return super().step()


sys.exit(driver_node.main(bus_factory=CrashingBus))
'''


def start(program, port, extra=()):
    args = [sys.executable, *program, '--ros-args', '-p', f'device:={port}']
    for prm in [*PARAMS, *extra]:
        args += ['-p', prm]
    proc = subprocess.Popen(args, env=testing.node_env(DOMAIN_ID), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    return proc, testing.ProcessOutput(proc)


def spin_until(ex, cond, timeout, proc, what):
    def alive():
        if proc.poll() is not None:
            raise AssertionError(f'driver_node exited ({proc.returncode}) while waiting for {what}')
    testing.spin_until(ex, cond, timeout, what, alive=alive)


def holds_port(proc, port) -> bool:
    """Whether the process has the serial device open (its file descriptors, read from /proc)."""
    target = os.path.realpath(port)
    fds = f'/proc/{proc.pid}/fd'
    return any(os.path.realpath(os.path.join(fds, fd)) == target for fd in os.listdir(fds))


class Traffic:
    """Every message the probe hears on the driver's topics, by topic."""

    DATA = {contract.JOINT_STATES: JointState, contract.SERVO_DIAGNOSTICS: ServoDiagnostics,
            contract.BUS_TIMING: BusTiming}        # silent unless active

    def __init__(self, node):
        self.node = node
        self.heard = {topic: [] for topic in [*self.DATA, contract.DIAGNOSTICS]}
        self.subs = [node.create_subscription(msg_type, topic, self.heard[topic].append, 500)
                     for topic, msg_type in {**self.DATA, contract.DIAGNOSTICS: DiagnosticArray}.items()]

    def stamped_within(self, topic: str, t0: float, t1: float = math.inf) -> list:
        return [m for m in self.heard[topic] if t0 < contract.stamp_seconds(m.header.stamp) < t1]

    def data_within(self, t0: float, t1: float) -> dict:
        """{topic: how many messages stamped in (t0, t1)} for the data topics that carried any."""
        counts = {topic: len(self.stamped_within(topic, t0, t1)) for topic in self.DATA}
        return {topic: n for topic, n in counts.items() if n}

    def close(self):
        for sub in self.subs:
            self.node.destroy_subscription(sub)


def inactive_window(ex, proc, out, traffic, emu, command) -> None:
    """In the inactive state: commands until the driver says it ignored one, and /diagnostics heard
    twice (its timer runs, and the data topics' would have). Meanwhile no data topic may carry a
    message stamped in the window (a stamp, not an arrival: nothing in flight counts) and the bus
    stays quiet."""
    t0, packets, goal = time.time(), emu.packets, emu.servo(1).get('goal_position')
    ignored = out.text().count('command ignored: the driver is not active')
    spin_until(ex, lambda: command(0.2) or (
        out.text().count('command ignored: the driver is not active') > ignored
        and len(traffic.stamped_within(contract.DIAGNOSTICS, t0)) >= 2), 30.0, proc,
        'a command refused and /diagnostics while inactive')
    assert traffic.data_within(t0, time.time()) == {}, 'a data topic published while inactive'
    assert emu.packets == packets and emu.servo(1).get('goal_position') == goal     # the bus is quiet


class Lifecycle:
    """The node's lifecycle services, called from the test's probe node."""

    def __init__(self, node, ex, proc):
        self.node, self.ex, self.proc = node, ex, proc
        name = NODE.node_name
        self.change = node.create_client(ChangeState, f'/{name}/change_state')
        self.get = node.create_client(GetState, f'/{name}/get_state')
        spin_until(ex, lambda: self.change.service_is_ready() and self.get.service_is_ready(), 30.0, proc,
                   'the lifecycle services')

    def state(self) -> str:
        for _ in range(3):                       # idempotent: a response lost right after discovery is asked again
            fut = self.get.call_async(GetState.Request())
            try:
                spin_until(self.ex, fut.done, 10.0, self.proc, 'get_state')
                return fut.result().current_state.label
            except AssertionError:
                if self.proc.poll() is not None:
                    raise
        raise AssertionError('get_state did not answer')

    def transition(self, transition_id: int, target: str) -> None:
        """Ask for a transition and wait until the node is in ``target`` (its answer, or its state)."""
        fut = self.change.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
        try:
            spin_until(self.ex, fut.done, 30.0, self.proc, f'the transition to {target}')
            assert fut.result().success, f'transition to {target} refused'
        except AssertionError:
            if fut.done():
                raise
        assert self.state() == target

    def close(self):
        self.node.destroy_client(self.change)
        self.node.destroy_client(self.get)


def test_lifecycle_transitions_through_the_running_node(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start(['-m', 'hexapod_driver.driver_node'], emu.port, ['autostart:=false'])
        traffic = Traffic(node)
        states, diags = traffic.heard[contract.JOINT_STATES], traffic.heard[contract.SERVO_DIAGNOSTICS]
        cmd_pub = node.create_publisher(JointState, contract.JOINT_COMMANDS, 10)

        def command(position):
            msg = JointState()
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.name, msg.position = ['leg1_coxa'], [position]
            cmd_pub.publish(msg)
        life = None
        try:
            life = Lifecycle(node, ex, proc)
            assert life.state() == 'unconfigured'
            assert emu.packets == 0 and not holds_port(proc, emu.port)      # nothing opened yet

            life.transition(Transition.TRANSITION_CONFIGURE, 'inactive')    # port open, servos verified
            assert holds_port(proc, emu.port)
            assert {e.instruction for e in emu.log} >= {p.PING, p.READ, p.WRITE}
            assert all(s.get('torque_enable') == 0 and s.get('return_delay_time') == 0 for s in emu.servos)
            assert emu.servo(1).get('cw_angle_limit') == 316                 # configured, torque off
            inactive_window(ex, proc, out, traffic, emu, command)          # configured, not active

            life.transition(Transition.TRANSITION_ACTIVATE, 'active')       # torque on, the loop runs
            assert all(s.get('torque_enable') == 1 and s.get('goal_position') == 512 for s in emu.servos)
            spin_until(ex, lambda: len(states) > 20 and diags, 30.0, proc, '/joint_states when active')
            assert all(s.torque_enabled for s in diags[-1].servos)
            goal = round(512 + 0.3 / robot.servo.rad_per_tick)
            spin_until(ex, lambda: command(0.3) or emu.servo(1).get('goal_position') == goal, 10.0, proc,
                       'a command while active')

            life.transition(Transition.TRANSITION_DEACTIVATE, 'inactive')   # loop stopped, torque off
            assert all(s.get('torque_enable') == 0 for s in emu.servos)
            inactive_window(ex, proc, out, traffic, emu, command)          # deactivated
            assert emu.servo(1).get('goal_position') == goal

            life.transition(Transition.TRANSITION_CLEANUP, 'unconfigured')  # port closed
            assert not holds_port(proc, emu.port)
            life.transition(Transition.TRANSITION_CONFIGURE, 'inactive')    # and opened again
            assert holds_port(proc, emu.port)
            life.transition(Transition.TRANSITION_ACTIVATE, 'active')
            assert all(s.get('torque_enable') == 1 for s in emu.servos)

            fut = life.change.call_async(ChangeState.Request(
                transition=Transition(id=Transition.TRANSITION_ACTIVE_SHUTDOWN)))
            proc.wait(timeout=30)                                           # shutdown ends the process
            assert not fut.done() or fut.result().success
        finally:
            if life is not None:
                life.close()
            rc, text = out.finish(proc, timeout=15.0)
            traffic.close()
            node.destroy_publisher(cmd_pub)
    assert rc == 0, text
    assert all(s.get('torque_enable') == 0 for s in emu.servos), text
    assert 'Traceback' not in text and 'torque off on all servos (read back); port closed' in text, text


def test_autostart_false_then_exit_leaves_the_port_untouched(robot, ros):
    node, ex = ros
    with BusEmulator(robot) as emu:
        proc, out = start(['-m', 'hexapod_driver.driver_node'], emu.port, ['autostart:=false'])
        life = None
        try:
            life = Lifecycle(node, ex, proc)
            assert life.state() == 'unconfigured'
        finally:
            if life is not None:
                life.close()
            rc, text = out.finish(proc, timeout=15.0)
    assert rc == 0 and emu.packets == 0, text
    assert 'Traceback' not in text, text


def test_exception_in_the_bus_loop_turns_torque_off_and_exits_non_zero(robot, ros, tmp_path):
    node, ex = ros
    script, trigger = tmp_path / 'crashing_driver.py', tmp_path / 'crash-now'
    script.write_text(CRASHING_DRIVER)
    with BusEmulator(robot) as emu:
        proc, out = start([str(script), str(trigger)], emu.port)
        states, diags = [], []
        subs = [node.create_subscription(JointState, contract.JOINT_STATES, states.append, 500),
                node.create_subscription(ServoDiagnostics, contract.SERVO_DIAGNOSTICS, diags.append, 10)]
        try:
            # crash only once diagnostics arrive here, so the ERROR cannot be lost to discovery
            spin_until(ex, lambda: diags and len(states) > 20, 60.0, proc, 'diagnostics')
            trigger.touch()
            testing.spin_until(ex, lambda: proc.poll() is not None and any(
                'bus loop crashed' in s.message for d in diags for s in d.servos), 60.0,
                'exit after the forced exception')
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            for s in subs:
                node.destroy_subscription(s)
        log = list(emu.log)
    assert rc == 3, text
    assert 'Traceback' in text and 'exception forced inside the bus loop' in text
    assert 'torque off on all servos (read back)' in text
    crash = next(i for i, e in enumerate(log) if e.servo_id == p.BROADCAST_ID and e.instruction == p.WRITE
                 and e.address == 24 and e.data == b'\x00')
    read_back = {e.servo_id for e in log[crash:] if e.instruction == p.READ and e.address == 24 and e.replied
                 and e.reply_params == b'\x00'}
    assert read_back == {s.servo_id for s in emu.servos}           # every id confirmed torque off
    assert all(s.get('torque_enable') == 0 for s in emu.servos)
    assert all(s.message.startswith('ERROR') for s in next(d for d in diags
                                                           if 'bus loop crashed' in d.servos[0].message).servos)
