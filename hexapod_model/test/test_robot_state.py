"""robot_state as a process: /robot_description (transient local) to a late subscriber; /tf from
/joint_states where tf2_msgs is installed, else one line saying so; a bad description is one
line and exit 2."""
import os
import signal
import subprocess
import sys
import time

import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from hexapod_model import contract  # noqa: E402
from hexapod_model.description import ALL_JOINTS, load_robot  # noqa: E402
from hexapod_model.tf_tree import TfTree, matrix_of  # noqa: E402
from hexapod_model.urdf import urdf_xml  # noqa: E402

DOMAIN_ID = 140 + os.getpid() % 20
try:
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None


def _env():
    return dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                PYTHONUNBUFFERED='1')


def test_robot_state_serves_the_description_and_tf():
    proc = subprocess.Popen([sys.executable, '-m', 'hexapod_model.robot_state'], env=_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    node = rclpy.create_node('robot_state_test', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    got, tfs = [], []
    try:
        time.sleep(1.0)                        # subscribe late: the description is latched
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(String, contract.ROBOT_DESCRIPTION, got.append, latched)
        pub = node.create_publisher(JointState, contract.JOINT_STATES, 10)
        if TFMessage is not None:
            node.create_subscription(TFMessage, contract.TF, tfs.append, 10)
        angles = [0.1 * (i % 5) - 0.2 for i in range(18)]
        t_end = time.monotonic() + 30.0
        while time.monotonic() < t_end and not (got and (TFMessage is None or tfs)):
            pub.publish(JointState(name=list(ALL_JOINTS), position=angles))
            ex.spin_once(timeout_sec=0.05)
        assert got and got[0].data == urdf_xml(load_robot())
        if TFMessage is not None:
            tree = TfTree(load_robot())
            tree.set_positions(ALL_JOINTS, angles)
            want = {c: (p, xyz, q) for p, c, xyz, q in tree.dynamic_entries()}
            for tr in tfs[-1].transforms:
                p, xyz, q = want[tr.child_frame_id]
                assert tr.header.frame_id == p and matrix_of(tr.transform)[:3, 3] == pytest.approx(list(xyz))
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert proc.returncode == 0, out
    assert 'Traceback' not in out
    if TFMessage is None:
        assert out.count('tf2_msgs is not installed') == 1, out


def test_bad_description_is_one_line(tmp_path):
    ov = tmp_path / 'bad.yaml'
    ov.write_text('links: {tibia: {mass_kg: -1.0}}\n')
    r = subprocess.run([sys.executable, '-m', 'hexapod_model.robot_state', '--ros-args', '-p',
                        f'robot_overlays:=["{ov}"]'], env=_env(), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and 'links.tibia.mass_kg' in r.stderr and 'Traceback' not in r.stderr + r.stdout
