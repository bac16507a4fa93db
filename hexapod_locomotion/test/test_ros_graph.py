"""The ROS graph as users run it, driven by /cmd_vel: lock-stepped over DDS (deterministic), in real
time with default parameters over DDS (the clocks agree), and composed in one process
(``hexapod_locomotion robot``, the real-time route). Judged on simulated time and message
contents; wall-clock limits are only failure bounds, except for the composed robot's simulated
seconds per wall second while recording (a ``realtime`` test)."""
import math
import os
import signal
import subprocess
import threading
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from hexapod_model.contract import stamp_seconds  # noqa: E402
from hexapod_testing import installed_executable  # noqa: E402

_exe = installed_executable
DOMAIN_ID = 1 + os.getpid() % 19          # 1..19: this file's processes and probe; DDS stays on loopback
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'    # the probe's context too


def _start(pkg, exe, *params, remap=()):
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    args = [_exe(pkg, exe), '--ros-args'] + [a for p in params for a in ('-p', p)] + \
        [a for r in remap for a in ('-r', r)]
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


class Probe:
    """Publishes /cmd_vel at 10 Hz and collects body pose, swing-down starts and detector reads."""

    def __init__(self, vx=0.05, wz=0.0, ns=''):
        from geometry_msgs.msg import PoseStamped, Twist
        from rclpy.executors import SingleThreadedExecutor

        from hexapod_msgs.msg import LegGroundDetection, SwingDownStart
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=DOMAIN_ID)
        self.node = rclpy.create_node('graph_probe', context=self.ctx)
        self.pose, self.swings, self.reads = [], [], []
        self.node.create_subscription(PoseStamped, f'{ns}/sim/body_pose', self._on_pose, 100)
        self.node.create_subscription(SwingDownStart, f'{ns}/swing_down', self.swings.append, 100)
        self.node.create_subscription(LegGroundDetection, f'{ns}/ground_detection', self.reads.append, 1000)
        pub = self.node.create_publisher(Twist, f'{ns}/cmd_vel', 10)
        self.twist = Twist()
        self.twist.linear.x, self.twist.angular.z = vx, wz
        self.node.create_timer(0.1, lambda: pub.publish(self.twist))
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        threading.Thread(target=self.ex.spin, daemon=True).start()

    def _on_pose(self, m):
        q = m.pose.orientation
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        self.pose.append((stamp_seconds(m.header.stamp), m.pose.position.x, yaw))

    def wait(self, done, procs, limit_s=240):
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline and not done(self):
            for p in procs:
                assert p.poll() is None, p.communicate()[0][-3000:]
            time.sleep(0.25)

    def close(self):
        self.ex.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


def _stop(procs, sig=signal.SIGINT):
    for p in procs:
        if p.poll() is None:
            p.send_signal(sig)
    outs = []
    for p in procs:
        try:
            outs.append(p.communicate(timeout=30)[0])
        except subprocess.TimeoutExpired:
            p.kill()
            outs.append(p.communicate()[0] + '\n<killed: did not stop within 30 s>')
    return outs


def _walked(probe):
    return probe.pose[-1][1] - probe.pose[0][1] if len(probe.pose) > 1 else 0.0


def _turned(probe):
    return probe.pose[-1][2] - probe.pose[0][2] if len(probe.pose) > 1 else 0.0


def test_lockstep_graph_walks_and_turns_by_cmd_vel():
    """Lock-step sim_node + locomotion_node, driven only by /cmd_vel (no default_vx): no deadlock
    between the /cmd_vel callback and the reads it must not wait for; walks > 5 cm and turns."""
    procs = [_start('hexapod_sim', 'sim_node', 'terrain:=flat', 'lockstep:=true')]
    procs.append(_start('hexapod_locomotion', 'locomotion_node', 'lockstep:=true',
                        't_des_s:=0.5'))
    probe = Probe(vx=0.05, wz=0.15)
    try:
        probe.wait(lambda p: _walked(p) > 0.06 and abs(_turned(p)) > 0.05, procs)
    finally:
        outs = _stop(procs)
        probe.close()
    assert _walked(probe) > 0.05, (probe.pose[:1], probe.pose[-1:], outs[1][-3000:])
    assert _turned(probe) > 0.05, (probe.pose[:1], probe.pose[-1:], outs[1][-3000:])   # wz > 0: to the left
    assert [p.returncode for p in procs] == [0, 0], outs
    assert 'Traceback' not in ''.join(outs), outs


@pytest.mark.realtime
def test_realtime_graph_with_default_parameters_accepts_the_sim_reads():
    """Two processes in real time, every parameter at its default (the sim stamps in sim time, the
    controller runs without use_sim_time): the controller accepts the reads, finds ground and walks."""
    procs = [_start('hexapod_sim', 'sim_node', 'terrain:=flat'), _start('hexapod_locomotion', 'locomotion_node')]
    probe = Probe(vx=0.05)
    try:
        probe.wait(lambda p: len(p.swings) >= 3 and any(r.stopped and r.stop_reason == 1 for r in p.reads), procs)
    finally:
        outs = _stop(procs)
        probe.close()
    assert 'locomotion stopped' not in outs[1], outs[1][-3000:]
    assert len(probe.swings) >= 3, outs[1][-3000:]
    sim_t = [p[0] for p in probe.pose]
    stamps = [stamp_seconds(r.header.stamp) for r in probe.reads]
    # on the sim's clock: the probe may see the sim's poses only after DDS discovery, seconds into the
    # run, so the newest read is compared with the newest pose (both taken when the walk was judged)
    assert stamps and sim_t and min(stamps) >= 0 and abs(max(stamps) - max(sim_t)) < 1, (min(stamps), max(stamps),
                                                                                         min(sim_t), max(sim_t))
    assert any(r.stopped and r.stop_reason == 1 for r in probe.reads), outs[1][-3000:]
    assert [p.returncode for p in procs] == [0, 0], outs
    assert 'Traceback' not in ''.join(outs), outs


@pytest.mark.realtime
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_composed_robot_walks_in_real_time_and_stops_cleanly(sig):
    """``hexapod_locomotion robot`` (sim + model + locomotion in one process, defaults, real time):
    walks by /cmd_vel at Algorithm 1's cadence in simulated time and ends with rc 0, no traceback."""
    procs = [_start('hexapod_locomotion', 'robot', 'terrain:=flat')]
    probe = Probe(vx=0.05)
    try:
        probe.wait(lambda p: _walked(p) > 0.06 and len(p.swings) >= 4, procs)
    finally:
        outs = _stop(procs, sig)
        probe.close()
    assert _walked(probe) > 0.05, outs[0][-3000:]
    # the reads of one leg within one swing-down come every t_con = 3 T_com (tripod) or later
    by_swing = {}
    for r in probe.reads:
        by_swing.setdefault((r.swing_start.sec, r.swing_start.nanosec, r.leg), []).append(
            stamp_seconds(r.header.stamp))
    gaps = sorted(b - a for v in by_swing.values() for a, b in zip(sorted(v), sorted(v)[1:]))
    assert gaps and gaps[0] > 0.003 - 1e-6, gaps[:5]
    assert procs[0].returncode == 0, outs
    assert 'Traceback' not in outs[0], outs[0][-3000:]
    assert 'serving /predict_swing_down' in outs[0]            # the model node is part of the graph


class JointProbe(Probe):
    """A :class:`Probe` that also keeps every /joint_states and /joint_commands it receives, and the
    wall-clock time each body pose arrived."""

    def __init__(self, vx=0.05):
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState
        self.pose_wall = []
        super().__init__(vx=vx)
        self.joints = {'/joint_states': [], '/joint_commands': []}
        for topic, got in self.joints.items():
            self.node.create_subscription(JointState, topic, lambda m, got=got: got.append(_joint_key(m)),
                                          QoSProfile(depth=1000))

    def _on_pose(self, m):
        super()._on_pose(m)
        self.pose_wall.append(time.monotonic())

    def real_time_factor(self, skip_s=1.0):
        """Simulated seconds per wall second over the poses received (the first ``skip_s`` of wall
        time left out: DDS discovery)."""
        pairs = [(w, p[0]) for w, p in zip(self.pose_wall, self.pose) if w >= self.pose_wall[0] + skip_s]
        (w0, s0), (w1, s1) = pairs[0], pairs[-1]
        return (s1 - s0) / (w1 - w0)


def _joint_key(m):
    return (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, tuple(m.name), tuple(m.position))


@pytest.mark.realtime
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_composed_robot_records_in_real_time_every_message_it_published(sig, tmp_path):
    """``robot record:=PATH``: the bag is written by a thread of its own and the robot keeps real time
    (it used to fall to 0.25-0.3 of it, rclpy's MultiThreadedExecutor busy-looping over the recording
    callbacks; measured in README.md). After Ctrl-C or SIGTERM the bag holds every /joint_states and
    /joint_commands a subscriber received, one /joint_states per read the bus counted on /bus_timing,
    every topic, and as many messages as the closing line says."""
    from hexapod_sim.bagio import BagReader
    bag = tmp_path / 'walk'
    procs = [_start('hexapod_locomotion', 'robot', 'terrain:=flat', f'record:={bag}')]
    probe = JointProbe(vx=0.05)
    try:
        probe.wait(lambda p: len(p.swings) >= 3 and len(p.joints['/joint_states']) > 2000
                   and p.pose_wall and p.pose_wall[-1] - p.pose_wall[0] > 10.0, procs)
    finally:
        outs = _stop(procs, sig)
        probe.close()
    out = outs[0]
    assert procs[0].returncode == 0 and 'Traceback' not in out, out[-3000:]
    rtf = probe.real_time_factor()
    assert rtf > 0.8 and 'cannot keep real_time_factor' not in out, (rtf, out[-3000:])
    closing = [line for line in out.splitlines() if 'bag closed:' in line]
    assert len(closing) == 1 and f'bag closed: {bag} (' in closing[0], out[-3000:]
    reader = BagReader(bag)
    assert reader.complete
    assert closing[0].endswith(f'({reader.message_count} messages)'), (closing, reader.message_count)
    topics = set(reader.topics())
    for name in ('joint_states', 'joint_commands', 'clock', 'imu', 'power', 'servo_diagnostics', 'diagnostics',
                 'bus_timing', 'sim/body_pose', 'sim/foot_contacts', 'ground_detection', 'swing_down', 'cmd_vel',
                 'read_schedule', 'tf', 'tf_static', 'robot_description'):
        assert f'/{name}' in topics, sorted(topics)
    for topic, seen in probe.joints.items():
        recorded = {_joint_key(m.msg) for m in reader.messages(topics=[topic])}
        missing = [k for k in seen if k not in recorded]
        assert seen and not missing, (topic, len(seen), len(recorded), missing[:3])
    # one /joint_states per read: the reads /bus_timing counted up to its last window are all there
    timing = [m.msg for m in reader.messages(topics=['/bus_timing'])]
    assert len(timing) >= 2
    last = timing[-1].header.stamp.sec * 1_000_000_000 + timing[-1].header.stamp.nanosec
    states = [_joint_key(m.msg)[0] for m in reader.messages(topics=['/joint_states'])]
    assert sum(t.reads for t in timing) == sum(1 for t in states if t < last)
    assert len(states) == len(set(states))                    # each read once


def test_the_whole_stack_runs_under_a_namespace():
    """Contract names are relative: ``-r __ns:=/hexa`` moves every topic and service of sim, model and
    locomotion node under /hexa, nothing stays at the root but /clock (rclpy's use_sim_time
    listens there), and the robot walks there (reads flow, swing-downs start, legs find ground)."""
    procs = [_start('hexapod_locomotion', 'robot', 'terrain:=flat', remap=['__ns:=/hexa'])]
    probe = Probe(vx=0.05, ns='/hexa')
    try:
        probe.wait(lambda p: len(p.swings) >= 2 and any(r.stopped and r.stop_reason == 1 for r in p.reads), procs)
        topics = dict(probe.node.get_topic_names_and_types())
        services = dict(probe.node.get_service_names_and_types())
    finally:
        outs = _stop(procs)
        probe.close()
    assert len(probe.swings) >= 2 and any(r.stopped and r.stop_reason == 1 for r in probe.reads), outs[0][-3000:]
    for name in ('joint_states', 'joint_commands', 'servo_diagnostics', 'bus_timing', 'imu', 'power',
                 'ground_detection', 'swing_down', 'cmd_vel', 'sim/body_pose', 'sim/foot_contacts'):
        assert f'/hexa/{name}' in topics, sorted(topics)
        assert f'/{name}' not in topics, sorted(topics)
    for name in ('predict_swing_down', 'set_read_schedule', 'emergency_stop'):
        assert f'/hexa/{name}' in services, sorted(services)
    assert '/clock' in topics
    assert 'serving /hexa/predict_swing_down' in outs[0]
    assert procs[0].returncode == 0 and 'Traceback' not in outs[0], outs[0][-3000:]


@pytest.mark.parametrize('param,named', [('hardware:=dynamixel', 'hardware'), ('terrain:=moon', 'moon'),
                                         ('gait:=bogus', 'bogus')])
def test_composed_robot_refuses_bad_parameters_in_one_line(param, named):
    p = _start('hexapod_locomotion', 'robot', param)
    out = p.communicate(timeout=120)[0]
    assert p.returncode != 0, out
    assert named in out and 'Traceback' not in out, out


def test_composed_robot_with_the_driver_walks_the_emulated_robot(tmp_path):
    """``robot hardware:=driver``: driver + model + locomotion in one process, the controller's thread
    running the AX-12A bus (the hardware path) against the bus emulator with MuJoCo physics in
    real time. Finds ground, walks (the emulator's physics says how far), Ctrl-C turns torque off."""
    np = pytest.importorskip('numpy')
    link, truth = tmp_path / 'ttyHEX', tmp_path / 'truth.npz'
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    emu = subprocess.Popen([_exe('hexapod_driver', 'bus_emulator'), '--backend', 'sim', '--terrain', 'flat',
                            '--link', str(link), '--truth-out', str(truth)],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert 'on ' in emu.stdout.readline(), 'the emulator did not start'
        procs = [_start('hexapod_locomotion', 'robot', 'hardware:=driver', f'device:={link}')]
        probe = Probe(vx=0.05)
        try:
            probe.wait(lambda p: len(p.swings) >= 5 and sum(r.stopped and r.stop_reason == 1 for r in p.reads) >= 6,
                       procs)
        finally:
            outs = _stop(procs)
            probe.close()
    finally:
        emu.send_signal(signal.SIGTERM)
        emu_out = emu.communicate(timeout=60)[0]
    assert procs[0].returncode == 0, outs[0][-3000:]
    assert 'Traceback' not in outs[0], outs[0][-3000:]
    # torque off broadcast at the end; read back from every servo unless the emulator, starved of CPU,
    # missed a reply (then the driver says which it could not confirm)
    assert 'torque off on all servos (read back)' in outs[0] or 'torque off confirmed for' in outs[0], outs[0][-3000:]
    assert sum(r.stopped and r.stop_reason == 1 for r in probe.reads) >= 6, outs[0][-3000:]
    body = np.load(truth)['truth']
    assert body.shape[0] > 100, emu_out
    assert body[-1, 2] - body[0, 2] > 0.02, (body[0, :5], body[-1, :5], outs[0][-3000:])    # x walked
