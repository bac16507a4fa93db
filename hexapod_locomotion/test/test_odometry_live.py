"""Leg odometry and live TF on the running robot: ``hexapod_locomotion robot`` (composed, real time,
recording) walks by /cmd_vel next to ``robot_state``; a subscriber receives /odom and a /tf + /tf_static
tree in which every foot chains up to ``odom``, and the bag carries /odom and ``odom -> base_link``.
Judged on message contents; wall-clock limits are only failure bounds."""
import os
import signal
import subprocess
import threading
import time

import pytest

rclpy = pytest.importorskip('rclpy')
pytest.importorskip('tf2_msgs.msg')

from hexapod_testing import installed_executable  # noqa: E402

DOMAIN_ID = 190 + os.getpid() % 20          # 190..209; DDS stays on loopback
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'


def _start(pkg, exe, *params):
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    args = [installed_executable(pkg, exe), '--ros-args'] + [a for p in params for a in ('-p', p)]
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


class TfProbe:
    def __init__(self):
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile

        from tf2_msgs.msg import TFMessage
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=DOMAIN_ID)
        self.node = rclpy.create_node('tf_probe', context=self.ctx)
        self.parent: dict[str, str] = {}
        self.odom: list = []
        self.lock = threading.Lock()
        self.node.create_subscription(TFMessage, '/tf', self._on_tf, 100)
        self.node.create_subscription(TFMessage, '/tf_static', self._on_tf,
                                      QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.node.create_subscription(Odometry, '/odom', self.odom.append, 100)
        pub = self.node.create_publisher(Twist, '/cmd_vel', 10)
        tw = Twist()
        tw.linear.x = 0.05
        self.node.create_timer(0.1, lambda: pub.publish(tw))
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        threading.Thread(target=self.ex.spin, daemon=True).start()

    def _on_tf(self, msg):
        with self.lock:
            for t in msg.transforms:
                self.parent[t.child_frame_id] = t.header.frame_id

    def chain(self, frame):
        out = [frame]
        with self.lock:
            while out[-1] in self.parent and len(out) < 20:
                out.append(self.parent[out[-1]])
        return out

    def close(self):
        self.ex.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


def _stop(procs):
    outs = []
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            outs.append(p.communicate(timeout=30)[0])
        except subprocess.TimeoutExpired:
            p.kill()
            outs.append(p.communicate()[0])
    return outs


def _run_until(procs, probe, done, timeout_s: float = 240.0) -> list[str]:
    """Wait until ``done()`` (or ``timeout_s``), every process alive meanwhile; stop them, close the
    probe, and return their outputs."""
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not done():
            for p in procs:
                assert p.poll() is None, p.communicate()[0][-3000:]
            time.sleep(0.25)
    finally:
        outs = _stop(procs)
        probe.close()
    return outs

def test_live_tf_from_odom_to_every_foot_while_the_robot_walks(tmp_path):
    bag = tmp_path / 'walk'
    procs = [_start('hexapod_locomotion', 'robot', 'terrain:=flat', f'record:={bag}'),
             _start('hexapod_model', 'robot_state')]
    probe = TfProbe()
    feet = [f'leg{leg}_foot' for leg in range(1, 7)]

    def done():
        return (len(probe.odom) > 5 and probe.odom[-1].pose.pose.position.x > 0.03
                and all(probe.chain(f)[-1] == 'odom' for f in feet))
    outs = _run_until(procs, probe, done)
    assert done(), (probe.chain('leg1_foot'), len(probe.odom), outs[0][-2000:])
    chain = probe.chain('leg1_foot')
    assert chain[-2:] == ['base_link', 'odom'], chain
    o = probe.odom[-1]
    assert o.header.frame_id == 'odom' and o.child_frame_id == 'base_link'
    assert o.pose.covariance[0] > 0 and o.pose.covariance[35] >= 0
    assert 'Traceback' not in outs[0], outs[0][-3000:]

    from hexapod_sim.bagio import BagReader
    r = BagReader(str(bag))
    assert r.topics().get('/odom', r.topics().get('odom')) == 'nav_msgs/msg/Odometry', r.topics()
    pairs = {(t.header.frame_id, t.child_frame_id) for m in r.messages(['/tf']) for t in m.msg.transforms}
    assert ('odom', 'base_link') in pairs and ('world', 'odom') in pairs, sorted(pairs)[:10]


@pytest.mark.parametrize('param,named', [('odom_frame:=my odom', 'odom_frame'), ('base_frame:=', 'base_frame'),
                                         ('heading_correction:=maybe', 'heading_correction')])
def test_locomotion_node_refuses_a_bad_odometry_parameter_in_one_line(param, named):
    p = _start('hexapod_locomotion', 'locomotion_node', param)
    out = p.communicate(timeout=120)[0]
    assert p.returncode != 0, out
    assert named in out and 'Traceback' not in out, out


def test_odom_advances_when_the_locomotion_node_runs_apart_from_the_sim():
    """Over DDS the odometry takes the bus master's background reads from the bus's own /joint_states
    subscription (RosBus.observe_reads): without them no foot is ever fresh and /odom stays at the start."""
    procs = [_start('hexapod_sim', 'sim_node', 'terrain:=flat'), _start('hexapod_locomotion', 'locomotion_node')]
    probe = TfProbe()

    def moved():
        return bool(probe.odom) and probe.odom[-1].pose.pose.position.x > 0.03
    outs = _run_until(procs, probe, moved)
    assert moved(), (len(probe.odom), outs[1][-2000:])
    assert 'Traceback' not in outs[0] + outs[1]
