"""Smoke tests of the workspace set-up itself (./hexapod setup), not of the robot code.

They prove that the ROS 2 Jazzy wheels, the DDS middleware, the built interface
package and the ament_python packages are all usable from the test environment.
"""
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_discovery_confined_to_localhost():
    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == 'LOCALHOST'
    assert os.environ.get('ROS_DOMAIN_ID', '').isdigit()


def test_interfaces_import():
    from diagnostic_msgs.msg import DiagnosticArray  # noqa: F401
    from rosgraph_msgs.msg import Clock  # noqa: F401
    from sensor_msgs.msg import JointState  # noqa: F401
    from std_srvs.srv import Trigger  # noqa: F401

    from hexapod_msgs.msg import LegGroundDetection
    from hexapod_msgs.srv import PredictSwingDown

    assert LegGroundDetection().stopped is False
    assert PredictSwingDown.Request().max_steps == 0


def test_workspace_packages_import_and_are_indexed():
    from ament_index_python.packages import get_package_share_directory

    for pkg in ('hexapod_msgs', 'hexapod_model', 'hexapod_sim', 'hexapod_driver', 'hexapod_locomotion'):
        if (ROOT / pkg / 'package.xml').exists():
            assert Path(get_package_share_directory(pkg), 'package.xml').exists(), pkg
    import hexapod_model  # noqa: F401


def test_joint_state_pub_sub_in_one_process():
    import rclpy
    from rclpy.context import Context
    from sensor_msgs.msg import JointState

    context = Context()
    # A domain of its own so a concurrent run cannot interfere.
    rclpy.init(context=context, domain_id=(os.getpid() % 50) + 150)
    try:
        node = rclpy.create_node('env_smoke_test', context=context)
        received = []
        pub = node.create_publisher(JointState, 'joint_states', 10)
        node.create_subscription(JointState, 'joint_states', received.append, 10)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 10.0
        while not received and time.monotonic() < deadline:
            pub.publish(JointState(name=['coxa_1'], position=[0.25]))
            executor.spin_once(timeout_sec=0.05)
        assert received, 'no JointState received within 10 s'
        assert list(received[0].name) == ['coxa_1']
        assert received[0].position[0] == pytest.approx(0.25)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


@pytest.mark.skipif(shutil.which('node') is None, reason='node not installed')
def test_mcap_node_tool_installed():
    out = subprocess.run(
        ['node', '-e', "console.log(typeof require('@mcap/core').McapIndexedReader)"],
        cwd=ROOT / 'tools' / 'mcap-node', capture_output=True, text=True, check=True)
    assert out.stdout.strip() == 'function'
