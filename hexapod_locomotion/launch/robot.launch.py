"""The real robot: driver_node (the AX-12A bus), model_node (/predict_swing_down) and
locomotion_node (Algorithm 1 over DDS, driven by cmd_vel), see docs/real-robot.md.

    ros2 launch hexapod_locomotion robot.launch.py [namespace:=hexa] [device:=/dev/ttyUSB0]
        [robot_overlays:="['/path/my_robot.yaml']"]

The robot's servo mounting (IDs, directions, offsets) is an overlay of the robot description that
every node loads (robot_overlays). Each node loads its package's config/<executable>.yaml (every
parameter at its default: copy and edit one, or override here).
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def config(package, file):
    """A node's parameter file as installed: share/<package>/config/<file>."""
    return PathJoinSubstitution([FindPackageShare(package), 'config', file])


def generate_launch_description():
    ns = LaunchConfiguration('namespace')
    robot = {'robot_description': LaunchConfiguration('robot_description'),
             'robot_overlays': LaunchConfiguration('robot_overlays')}
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='', description='namespace of every topic and service'),
        DeclareLaunchArgument('robot_description', default_value='',
                              description="robot description YAML ('' = the packaged robot.yaml)"),
        DeclareLaunchArgument('robot_overlays', default_value="['']",
                              description="overlay YAMLs merged over the description (your robot's mounting), "
                                          'as a YAML list'),
        DeclareLaunchArgument('device', default_value='/dev/hexapod_dynamixel',
                              description='serial device of the Dynamixel adapter'),
        Node(package='hexapod_driver', executable='driver_node', name='hexapod_driver', namespace=ns,
             output='screen',
             parameters=[config('hexapod_driver', 'driver_node.yaml'), robot,
                         {'device': LaunchConfiguration('device')}]),
        Node(package='hexapod_model', executable='model_node', name='model_node', namespace=ns, output='screen',
             parameters=[config('hexapod_model', 'model_node.yaml'), robot]),
        Node(package='hexapod_locomotion', executable='locomotion_node', name='locomotion_node', namespace=ns,
             output='screen',
             parameters=[config('hexapod_locomotion', 'locomotion_node.yaml'), robot]),
    ])
