"""terrain_node: the terrain under the robot, once per gait cycle, from the servo feedback alone.

Subscribes the controller's streams - ``/joint_commands``, ``/joint_states``, ``/swing_down``,
``/ground_detection`` and (optional) ``/power`` - feeds them to the gait-cycle features
(:mod:`hexapod_locomotion.core.terrain_features`) and, when a gait cycle closes (every leg has swung down
once), publishes its class with the confidence on ``/terrain`` (hexapod_msgs/msg/TerrainClass) and
logs one line. The sim node records ``/terrain`` in its bag; ``./hexapod analyse BAG`` prints the
timeline. The model file is the packaged one unless ``model`` names another (``./hexapod terrain
train``); a model file this code cannot use stops the node at start with one line.

  ros2 run hexapod_locomotion terrain_node --ros-args -p model:=my_robot_terrain.pkl
"""
from __future__ import annotations

from rclpy.node import Node

from hexapod_locomotion.core.terrain_features import CycleFeatureExtractor, feed_message
from hexapod_locomotion.core.terrain_model import DEFAULT_MODEL, TerrainModel, TerrainModelError
from hexapod_locomotion.nodes.params import TERRAIN_NODE, TerrainNodeParams
from hexapod_model.contract import GROUND_DETECTION, JOINT_COMMANDS, JOINT_STATES, POWER, SWING_DOWN, TERRAIN, stamp_parts
from hexapod_model.description import DescriptionError
from hexapod_model.node_params import NodeParams, node_help, run_node
from hexapod_model.param_schema import RobotSource


class TerrainNode(Node):
    def __init__(self, model: TerrainModel | None = None, robot=None, **node_kwargs):
        """``model`` / ``robot``: the classifier and the description (None: from the parameters)."""
        super().__init__('terrain_node', **node_kwargs)
        params = NodeParams(self)
        source = params.declare(RobotSource)
        path = params.declare(TerrainNodeParams).model or str(DEFAULT_MODEL)
        self.model = model if model is not None else TerrainModel.load(path)
        self.robot = robot if robot is not None else source.load()
        self.extractor = CycleFeatureExtractor(self.robot)
        from sensor_msgs.msg import BatteryState, JointState

        from hexapod_msgs.msg import LegGroundDetection, SwingDownStart, TerrainClass
        self._msg = TerrainClass
        self.pub = self.create_publisher(TerrainClass, TERRAIN, 10)
        for msg_type, topic, depth in ((JointState, JOINT_STATES, 1000), (JointState, JOINT_COMMANDS, 1000),
                                       (LegGroundDetection, GROUND_DETECTION, 1000), (SwingDownStart, SWING_DOWN, 100),
                                       (BatteryState, POWER, 100)):
            self.create_subscription(msg_type, topic, lambda m, t=topic: self._on(t, m), depth)
        self.cycles = 0
        self.get_logger().info(f'terrain classes {", ".join(self.model.classes)} '
                               f'(model {path}, code {self.model.provenance.get("code_version", "?")})')

    def _on(self, topic: str, msg) -> None:
        cycle = feed_message(self.extractor, topic, msg, 0.0)
        if cycle is None:
            return
        probs = self.model.probabilities(cycle.values)[0]
        names = [str(c) for c in self.model.estimator.classes_]
        best = int(probs.argmax())
        m = self._msg()
        m.header.stamp.sec, m.header.stamp.nanosec = stamp_parts(cycle.t_end_s)
        m.cycle_start.sec, m.cycle_start.nanosec = stamp_parts(cycle.t_start_s)
        m.terrain, m.confidence = names[best], float(probs[best])
        m.classes, m.probabilities = names, [float(p) for p in probs]
        self.pub.publish(m)
        self.cycles += 1
        self.get_logger().info(f'gait cycle {self.cycles} ({cycle.t_start_s:.2f}-{cycle.t_end_s:.2f} s): '
                               f'{m.terrain} ({100 * m.confidence:.0f} %)')


def main(args=None):
    run_node('terrain_node', TerrainNode, node_help('terrain_node', __doc__, TERRAIN_NODE.schemas), args,
             errors=(TerrainModelError, DescriptionError), spec=TERRAIN_NODE)


if __name__ == '__main__':
    main()
