"""The real robot: the AX-12A bus (driver_node), /predict_swing_down (model_node) and Algorithm 1
driven by cmd_vel (locomotion_node), see docs/real-robot.md.

    ros2 launch hexapod_locomotion robot.launch.py [namespace:=hexa] [device:=/dev/ttyUSB0]
        [robot_overlays:="['/path/my_robot.yaml']"] [route:=composed|processes]

route:=composed (the default) runs the three nodes in one process, ``hexapod_locomotion robot
hardware:=driver``: the controller owns the bus and reads, decides and writes at Algorithm 1's
cadence, t_con = L x T_com. route:=processes runs them as three processes talking over DDS, which
on a small computer cannot hold that cadence (measured in docs/architecture.md); the topics,
services and parameters are the same either way.

The robot's servo mounting (IDs, directions, offsets) is an overlay of the robot description that
every node loads (robot_overlays). Each node loads its package's config/<executable>.yaml (every
parameter at its default: copy and edit one, or override here).
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def config(package, file):
    """A node's parameter file as installed: share/<package>/config/<file>."""
    return PathJoinSubstitution([FindPackageShare(package), 'config', file])


def generate_launch_description():
    ns = LaunchConfiguration('namespace')
    robot = {'robot_description': LaunchConfiguration('robot_description'),
             'robot_overlays': LaunchConfiguration('robot_overlays')}
    driver = {'device': LaunchConfiguration('device')}
    is_composed = PythonExpression(["'", LaunchConfiguration('route'), "' == 'composed'"])
    composed, processes = IfCondition(is_composed), UnlessCondition(is_composed)
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='', description='namespace of every topic and service'),
        DeclareLaunchArgument('robot_description', default_value='',
                              description="robot description YAML ('' = the packaged robot.yaml)"),
        DeclareLaunchArgument('robot_overlays', default_value="['']",
                              description="overlay YAMLs merged over the description (your robot's mounting), "
                                          'as a YAML list'),
        DeclareLaunchArgument('device', default_value='/dev/hexapod_dynamixel',
                              description='serial device of the Dynamixel adapter'),
        DeclareLaunchArgument('route', default_value='composed', choices=['composed', 'processes'],
                              description='composed: one process, the controller owning the bus (real time); '
                                          'processes: three processes over DDS'),
        # one process: every node keeps its name, so each parameter file addresses its node
        Node(package='hexapod_locomotion', executable='robot', namespace=ns, output='screen', condition=composed,
             parameters=[config('hexapod_driver', 'driver_node.yaml'), config('hexapod_model', 'model_node.yaml'),
                         config('hexapod_locomotion', 'locomotion_node.yaml'), robot, driver,
                         {'hardware': 'driver'}]),
        Node(package='hexapod_driver', executable='driver_node', name='hexapod_driver', namespace=ns,
             output='screen', condition=processes,
             parameters=[config('hexapod_driver', 'driver_node.yaml'), robot, driver]),
        Node(package='hexapod_model', executable='model_node', name='model_node', namespace=ns, output='screen',
             condition=processes, parameters=[config('hexapod_model', 'model_node.yaml'), robot]),
        Node(package='hexapod_locomotion', executable='locomotion_node', name='locomotion_node', namespace=ns,
             output='screen', condition=processes,
             parameters=[config('hexapod_locomotion', 'locomotion_node.yaml'), robot]),
    ])
