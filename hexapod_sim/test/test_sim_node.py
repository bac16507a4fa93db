"""sim_node over ROS (in-process executor, loopback, own ROS_DOMAIN_ID): the driver's interface,
lock-step and paced runs, and a recorded bag read back by rosbags and by @mcap/core (Node.js)."""
import base64
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import BatteryState, Imu, JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

import hexapod_testing as testing  # noqa: E402
from hexapod_model import contract  # noqa: E402
from hexapod_model.description import ALL_JOINTS, load_robot  # noqa: E402
from hexapod_model.servo import theta_to_tick  # noqa: E402
from hexapod_msgs.msg import ReadSchedule, ServoDiagnostics  # noqa: E402
from hexapod_sim.node.sim_node import SimNode  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
DOMAIN_ID = 60 + os.getpid() % 40          # test-specific domain; DDS stays on loopback
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)


@pytest.fixture
def ctx():
    c = rclpy.Context()
    rclpy.init(context=c, domain_id=DOMAIN_ID)
    yield c
    rclpy.try_shutdown(context=c)


class Probe:
    """The controller side: publishes commands/schedules, records everything the sim publishes."""

    def __init__(self, ctx):
        self.node = rclpy.create_node('probe', context=ctx)
        n = self.node
        self.cmd = n.create_publisher(JointState, contract.JOINT_COMMANDS, 1000)
        self.schedule = n.create_publisher(ReadSchedule, contract.READ_SCHEDULE, 10)
        self.got = {t: [] for t in (contract.JOINT_STATES, contract.CLOCK, contract.IMU, contract.POWER,
                                    contract.SERVO_DIAGNOSTICS)}
        types = {contract.JOINT_STATES: JointState, contract.CLOCK: Clock, contract.IMU: Imu,
                 contract.POWER: BatteryState, contract.SERVO_DIAGNOSTICS: ServoDiagnostics}
        self.subs = [n.create_subscription(types[t], t, (lambda m, t=t: self.got[t].append(m)), 1000)
                     for t in self.got]
        self.estop = n.create_client(Trigger, contract.EMERGENCY_STOP)
        self.sent = 0

    def command(self, names=(), positions=()):
        self.cmd.publish(JointState(name=list(names), position=list(positions)))
        self.sent += 1


def spin_until(ex, cond, timeout=20.0):
    testing.spin_until(ex, cond, timeout)


def stamp_ns(msg) -> int:
    return contract.stamp_ns(msg.header.stamp)


def test_lockstep_commands_move_the_joint_and_reads_are_spaced_by_t_com(ctx, tmp_path):
    bag = tmp_path / 'run'
    sim = SimNode(context=ctx, parameter_overrides=[
        Parameter('lockstep', value=True), Parameter('record', value=str(bag)),
        Parameter('bus_timing_rate_hz', value=10.0)])
    probe = Probe(ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(sim)
    ex.add_node(probe.node)
    robot = load_robot()
    t_com_ns = int(round(sim.sim.t_com_s * 1e9))
    try:
        spin_until(ex, lambda: probe.cmd.get_subscription_count() >= 1 and probe.schedule.get_subscription_count() >= 1
                   and all(s.get_publisher_count() >= 1 for s in probe.subs))
        assert sim.sim.now() == 0.0                       # lock-step: nothing moves before a command
        probe.schedule.publish(ReadSchedule(joint_names=['leg1_femur']))
        spin_until(ex, lambda: sim.loop.schedule == ('leg1_femur',))
        states = probe.got[contract.JOINT_STATES]
        goal = 0.9
        for k in range(300):                               # Algorithm 1 style: write, then read
            probe.command(['leg1_femur'], [goal])
            spin_until(ex, lambda: len(states) == k + 1)
        stamps = np.array([stamp_ns(m) for m in states])
        assert np.all(np.diff(stamps) == t_com_ns)          # one read per cycle, t_com apart
        assert all(m.name == ['leg1_femur'] for m in states)
        pos = np.array([m.position[0] for m in states])
        assert pos[0] == pytest.approx(robot.default_stance_rad[1], abs=robot.servo.rad_per_tick)
        ticks = theta_to_tick(pos, robot.servo)
        assert np.all(ticks == np.round(ticks))            # the servo reports integer ticks
        assert abs(theta_to_tick(goal, robot.servo) - ticks[-1]) < 8    # reached (gravity sag: a few ticks)
        assert pos[-1] - pos[0] > 0.3                       # the commanded joint moved (and settled, above)
        # back to the default schedule: all 18 joints in order, still t_com apart
        probe.schedule.publish(ReadSchedule(joint_names=[]))
        spin_until(ex, lambda: sim.loop.schedule == ALL_JOINTS)
        for k in range(2):
            probe.command()                                 # no goals: just advance one cycle
            spin_until(ex, lambda: len(states) == 300 + 18 * (k + 1))
        assert [m.name[0] for m in states[300:]] == list(ALL_JOINTS) * 2
        assert np.all(np.diff([stamp_ns(m) for m in states[299:]]) == t_com_ns)
        # emergency stop: torque off everywhere, visible in the diagnostics
        assert probe.estop.wait_for_service(timeout_sec=10.0)
        fut = probe.estop.call_async(Trigger.Request())
        spin_until(ex, fut.done)
        assert fut.result().success and 'torque off' in fut.result().message
        n_diag = len(probe.got[contract.SERVO_DIAGNOSTICS])
        while len(probe.got[contract.SERVO_DIAGNOSTICS]) == n_diag:
            n_states = len(states)
            probe.command()
            spin_until(ex, lambda: len(states) == n_states + 18)
            ex.spin_once(timeout_sec=0.01)
        diag = probe.got[contract.SERVO_DIAGNOSTICS][-1]
        assert [s.joint_name for s in diag.servos] == list(ALL_JOINTS)
        assert not any(s.torque_enabled for s in diag.servos)
        assert [s.id for s in diag.servos] == [b.servo_id for b in robot.bus.joints]
        assert all(25.0 < s.temperature_c < 40.0 and s.voltage_v == robot.servo.supply_voltage_v for s in diag.servos)
        # the other outputs
        imu = probe.got[contract.IMU]
        assert len(imu) > 100
        imu_t = np.array([stamp_ns(m) for m in imu])
        assert np.all(np.diff(imu_t) == 2_500_000)          # 400 Hz, exact stamps
        # standing: the accelerometer reads +g (at t = 0 the robot is dropped from 0.5 mm: free fall)
        assert np.median([m.linear_acceleration.z for m in imu]) == pytest.approx(robot.gravity_mps2, abs=0.2)
        power = probe.got[contract.POWER]
        assert len(power) > 10 and all(p.voltage == robot.servo.supply_voltage_v and p.current < 0 for p in power)
        clock = probe.got[contract.CLOCK]
        assert len(clock) > 100 and contract.stamp_ns(clock[-1].clock) <= sim.sim.now() * 1e9 + 1
    finally:
        sim.close()
        ex.remove_node(sim)
        sim.destroy_node()
        probe.node.destroy_node()
    _check_bag_with_independent_readers(bag, probe)


def _check_bag_with_independent_readers(bag: Path, probe: Probe):
    """rosbags decodes exactly what the probe received; @mcap/core sees the same bytes and times."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    assert (bag / 'metadata.yaml').is_file() and list(bag.glob('*.mcap'))
    store = get_typestore(Stores.EMPTY)
    raw = []
    with Reader(bag) as reader:
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        topics = {contract.topic_key(c.topic): c.msgtype for c in reader.connections}     # the contract's names
        for conn, t, data in reader.messages():
            raw.append((contract.topic_key(conn.topic), t, bytes(data)))
        decoded = [(contract.topic_key(c.topic), store.deserialize_cdr(d, c.msgtype)) for c, _, d in reader.messages()]
    for topic in (contract.JOINT_STATES, contract.JOINT_COMMANDS, contract.READ_SCHEDULE, contract.CLOCK, contract.IMU,
                  contract.POWER, contract.SERVO_DIAGNOSTICS, contract.BUS_TIMING, contract.SIM_TRUTH_CONTACTS,
                  contract.SIM_TRUTH_POSE):
        assert topics[contract.topic_key(topic)] == contract.MSG_TYPES.get(topic, topics[contract.topic_key(topic)]), topic
    js = [m for t, m in decoded if t == contract.JOINT_STATES]
    got = probe.got[contract.JOINT_STATES]
    assert len(js) == len(got)
    for a, b in zip(js, got):
        assert (a.header.stamp.sec, a.header.stamp.nanosec) == (b.header.stamp.sec, b.header.stamp.nanosec)
        assert list(a.name) == list(b.name) and list(a.position) == list(b.position)
    imu = [m for t, m in decoded if t == contract.IMU]
    assert [m.linear_acceleration.z for m in imu[:len(probe.got[contract.IMU])]] == \
        [m.linear_acceleration.z for m in probe.got[contract.IMU]]
    cmds = [m for t, m in decoded if t == contract.JOINT_COMMANDS]
    assert len(cmds) == probe.sent                         # every command received was recorded
    assert all(list(m.name) == ['leg1_femur'] and m.position[0] == 0.9 for m in cmds[:300])
    assert all(len(m.name) == 0 for m in cmds[300:])

    if shutil.which('node') is None:
        pytest.skip('node is not installed: the @mcap/core cross-check needs Node.js')
    reader_js = REPO / 'tools' / 'mcap-node' / 'read.mjs'
    if not (REPO / 'tools' / 'mcap-node' / 'node_modules' / '@mcap' / 'core').is_dir() or not reader_js.is_file():
        pytest.skip('tools/mcap-node (@mcap/core and read.mjs) not set up; ./hexapod setup runs npm ci')
    res = subprocess.run(['node', str(reader_js), str(bag)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    theirs = sorted((contract.topic_key(m['topic']), int(m['logTime']), base64.b64decode(m['data']))
                    for m in doc['messages'])
    assert theirs == sorted(raw)


@pytest.mark.realtime
def test_paced_run_does_not_outrun_the_real_time_factor(ctx):
    sim = SimNode(context=ctx, parameter_overrides=[Parameter('real_time_factor', value=1.0)])
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(sim)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0:
            ex.spin_once(timeout_sec=0.01)
            assert sim.sim.now() <= (time.monotonic() - t0) * 1.0 + 0.05
        assert sim.sim.now() > 0.05                         # it did run
        sim.set_parameters([Parameter('real_time_factor', value=0.0)])
        t_sim, t0 = sim.sim.now(), time.monotonic()
        while time.monotonic() - t0 < 0.5:
            ex.spin_once(timeout_sec=0.01)
        assert sim.sim.now() > t_sim                        # as fast as possible now
        bad = sim.set_parameters([Parameter('real_time_factor', value=-1.0)])[0]
        assert not bad.successful and 'real_time_factor' in bad.reason
    finally:
        sim.close()
        sim.destroy_node()


def test_diagnostics_and_robot_description_over_ros(ctx):
    """/diagnostics (diagnostic_msgs): every servo and the bus of the simulated robot, OK, in
    simulated time; /robot_description (transient local) reaches a late subscriber."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from std_msgs.msg import String

    from hexapod_model.urdf import urdf_xml
    sim = SimNode(context=ctx, parameter_overrides=[
        Parameter('real_time_factor', value=0.0), Parameter('bus_timing_rate_hz', value=10.0)])
    node = rclpy.create_node('diag_probe', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(sim)
    ex.add_node(node)
    diags, desc = [], []
    try:
        for _ in range(20):
            ex.spin_once(timeout_sec=0.01)           # the description goes out before anyone listens
        node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, diags.append, 100)
        node.create_subscription(String, contract.ROBOT_DESCRIPTION, desc.append,
                                 QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        names = lambda: {s.name for m in diags for s in m.status}  # noqa: E731
        spin_until(ex, lambda: desc and len(names()) == 19, timeout=60.0)
        assert desc[0].data == urdf_xml(sim.sim.robot)
        assert all(s.level == b'\x00' for m in diags for s in m.status), [
            (s.name, s.message) for m in diags for s in m.status if s.level != b'\x00']
        bus = next(s for m in diags for s in m.status if s.name == 'sim_node: bus')
        values = {kv.key: kv.value for kv in bus.values}
        assert float(values['t_com_mean_ms']) == pytest.approx(sim.sim.t_com_s * 1e3)
        assert float(values['read_rate_hz']) == pytest.approx(1.0 / sim.sim.t_com_s, rel=0.05)
        assert stamp_ns(diags[-1]) <= int(sim.sim.now() * 1e9)             # simulated time
    finally:
        sim.close()
        node.destroy_node()
        sim.destroy_node()


def test_recording_callbacks_do_not_wait_for_a_bus_transaction(ctx, tmp_path):
    """The recording subscriptions (/cmd_vel, /ground_detection, /swing_down) only hand the message to
    the bag's writer thread: they run while a bus transaction holds the sim's lock, as the composed
    robot's controller thread does for every read (they used to wait for that lock, so the executor
    thread waited for the controller). The bag holds every /cmd_vel sent, in order."""
    import threading

    from geometry_msgs.msg import Twist, Vector3

    from hexapod_sim.bagio import BagReader
    bag = tmp_path / 'bag'
    sim = SimNode(context=ctx, parameter_overrides=[Parameter('lockstep', value=True),
                                                    Parameter('record', value=str(bag))])
    node = rclpy.create_node('cmd_vel_probe', context=ctx)
    pub = node.create_publisher(Twist, contract.CMD_VEL, 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(sim)
    ex.add_node(node)
    held, release, stop = threading.Event(), threading.Event(), threading.Event()

    def transaction():                        # a bus transaction that does not end until released
        with sim._lock:
            held.set()
            release.wait(60.0)

    def spin():
        while not stop.is_set():
            ex.spin_once(timeout_sec=0.05)
    threads = [threading.Thread(target=transaction, daemon=True), threading.Thread(target=spin, daemon=True)]
    threads[0].start()
    held.wait(10.0)
    threads[1].start()
    sent = []
    recorded = lambda: sim.recorder.count - 2          # noqa: E731 - after the robot description, /tf_static
    try:
        deadline = time.monotonic() + 30.0    # failure bound only
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)                  # the sim's /cmd_vel subscription matched: nothing sent is lost
        while recorded() < 5 and time.monotonic() < deadline:
            if len(sent) < 5:
                sent.append(0.01 * (len(sent) + 1))
                pub.publish(Twist(linear=Vector3(x=sent[-1])))
            time.sleep(0.1)
        assert threads[0].is_alive() and not release.is_set()      # the transaction held the lock throughout
        assert recorded() == 5, f'{recorded()} of {len(sent)} /cmd_vel recorded while the bus was busy'
    finally:
        release.set()
        stop.set()
        for t in threads:
            t.join(10.0)
        sim.close()
        node.destroy_node()
        sim.destroy_node()
    got = [m.msg.linear.x for m in BagReader(bag).messages(topics=['/cmd_vel'])]
    assert got == sent


def test_a_recording_error_is_one_line_and_the_node_runs_on(ctx, tmp_path, capfd):
    """A write the bag refuses (here a message of another type on a recorded topic) stops the
    recording with one error line; the sim keeps serving, and closing says how much the bag holds."""
    from hexapod_sim.bagio import BagReader
    bag = tmp_path / 'bag'
    sim = SimNode(context=ctx, parameter_overrides=[Parameter('lockstep', value=True),
                                                    Parameter('record', value=str(bag))])
    rec = sim.recorder
    try:
        rec.write(contract.CLOCK, 'rosgraph_msgs/msg/Clock', {'clock': contract.stamp_dict(0.0)}, 0.0)
        rec.write(contract.CLOCK, 'std_msgs/msg/String', {'data': 'not a clock'}, 0.001)
        deadline = time.monotonic() + 30.0                # failure bound only
        while rec.error is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert rec.error is not None
        with sim._lock:                                   # the node still steps (one lock-step cycle)
            for ev in sim.loop.run(max_reads=sim.loop.cycle_reads):
                sim._publish(ev)
    finally:
        sim.close()
        sim.destroy_node()
    err = capfd.readouterr().err
    failed = [line for line in err.splitlines() if 'recording stopped' in line]
    assert len(failed) == 1 and '[ERROR]' in failed[0], err
    assert 'clock: topic /clock is recorded as rosgraph_msgs/msg/Clock, cannot write std_msgs/msg/String' in failed[0]
    closing = [line for line in err.splitlines() if 'bag closed' in line]
    n = BagReader(bag).message_count
    assert len(closing) == 1 and f'({n} messages; recording had stopped on the error above)' in closing[0], err
    assert '[ERROR]' not in closing[0] and 'Traceback' not in err
    assert n == 4                                         # robot description, /tf_static, /sim/scene, the first /clock
