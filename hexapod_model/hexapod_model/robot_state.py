"""robot_state: the robot model and its transforms for the real robot (what the sim node and the
bags carry for the simulated one).

Out: ``/robot_description`` (std_msgs/String, transient local): the URDF of the description and
overlays (hexapod_model.urdf); ``/tf_static`` (transient local) and ``/tf`` at ``tf_rate_hz``:
``base_link -> ... -> leg{l}_{role}`` from the latest ``/joint_states`` of each joint (the driver
publishes one joint per read), hexapod_model.tf_tree. No body pose: without an estimator there is
no ``world -> base_link``; RViz and Foxglove show the robot in ``base_link``.

``/tf`` needs the tf2_msgs Python package (ros-jazzy-tf2-msgs, part of every ROS 2 install). The
PyPI wheels have none: ``./hexapod setup`` then builds the workspace's one-message ``tf2_msgs``
package. Without either, the node says so once and serves ``/robot_description`` only (bags carry
TF regardless, their writer has the definition built in).

    ros2 run hexapod_model robot_state [--ros-args -p tf_rate_hz:=50.0]
"""
from __future__ import annotations

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from hexapod_model import contract
from hexapod_model.description import DescriptionError
from hexapod_model.node_params import NodeParams, node_help, run_node
from hexapod_model.param_schema import ROBOT_STATE_NODE, RobotSource, RobotStateParams
from hexapod_model.tf_tree import TfTree
from hexapod_model.urdf import urdf_xml

try:
    from geometry_msgs.msg import TransformStamped

    from tf2_msgs.msg import TFMessage
except ImportError:                 # the PyPI wheels have no tf2_msgs (see the module doc)
    TFMessage = None


def tf_message(entries, stamp):
    """tf2_msgs/TFMessage of (parent, child, xyz, quat xyzw) entries, all stamped ``stamp``."""
    msg = TFMessage()
    for parent, child, xyz, q in entries:
        t = TransformStamped()
        t.header.stamp, t.header.frame_id, t.child_frame_id = stamp, parent, child
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = xyz
        r = t.transform.rotation
        r.x, r.y, r.z, r.w = q
        msg.transforms.append(t)
    return msg


class RobotStateNode(Node):
    def __init__(self, **node_kwargs):
        super().__init__('robot_state', **node_kwargs)
        params = NodeParams(self)
        robot = params.declare(RobotSource).load()
        rate = params.declare(RobotStateParams).tf_rate_hz
        self.tree = TfTree(robot)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        if TFMessage is None:          # said before the description goes out: a listener that has it has this too
            self.get_logger().warning('tf2_msgs is not installed (apt install ros-jazzy-tf2-msgs): serving '
                                      f'{contract.ROBOT_DESCRIPTION} only, no /tf')
        self.create_publisher(String, contract.ROBOT_DESCRIPTION, latched).publish(String(data=urdf_xml(robot)))
        self.create_subscription(JointState, contract.JOINT_STATES, self.on_joint_states, 200)
        if TFMessage is None:
            return
        self.pub_tf = self.create_publisher(TFMessage, contract.TF, 100)
        static = self.create_publisher(TFMessage, contract.TF_STATIC, latched)
        static.publish(tf_message(self.tree.static_entries(), self.get_clock().now().to_msg()))
        self.create_timer(1.0 / rate, self.on_timer)
        self.get_logger().info(f'serving {contract.ROBOT_DESCRIPTION} and /tf of {robot.name!r} at {rate:g} Hz')

    def on_joint_states(self, msg: JointState) -> None:
        if len(msg.name) == len(msg.position):
            self.tree.set_positions(msg.name, msg.position)

    def on_timer(self) -> None:
        entries = self.tree.dynamic_entries()
        if entries:
            self.pub_tf.publish(tf_message(entries, self.get_clock().now().to_msg()))


def main(args=None):
    run_node('robot_state', RobotStateNode,
             node_help('robot_state', __doc__, ROBOT_STATE_NODE.schemas), args, errors=(DescriptionError,),
             spec=ROBOT_STATE_NODE)


if __name__ == '__main__':
    main()
