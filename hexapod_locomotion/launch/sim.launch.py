"""The simulated robot as three processes: sim_node (the MuJoCo hexapod, the driver's interface),
model_node (/predict_swing_down) and locomotion_node (Algorithm 1 over DDS, driven by cmd_vel).

    ros2 launch hexapod_locomotion sim.launch.py [namespace:=hexa] [terrain:=mockup]
        [robot_overlays:="['/path/my_robot.yaml']"] [lockstep:=true]

Each node loads its package's config/<executable>.yaml (every parameter at its default: copy and
edit one, or override here). Over DDS the real-time walk cannot hold Algorithm 1's cadence on a
small machine; lockstep:=true runs it exact (docs/architecture.md), the composed
``ros2 run hexapod_locomotion robot`` runs it in real time.
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
    lockstep = LaunchConfiguration('lockstep')
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='', description='namespace of every topic and service'),
        DeclareLaunchArgument('robot_description', default_value='',
                              description="robot description YAML ('' = the packaged robot.yaml)"),
        DeclareLaunchArgument('robot_overlays', default_value="['']",
                              description='overlay YAMLs merged over the description, as a YAML list'),
        DeclareLaunchArgument('terrain', default_value='mockup', description='flat, blocks, stairs, rough, mockup'),
        DeclareLaunchArgument('lockstep', default_value='false',
                              description='deterministic lock-step of sim and controller over DDS'),
        Node(package='hexapod_sim', executable='sim_node', name='sim_node', namespace=ns, output='screen',
             parameters=[config('hexapod_sim', 'sim_node.yaml'), robot,
                         {'terrain': LaunchConfiguration('terrain'), 'lockstep': lockstep}]),
        Node(package='hexapod_model', executable='model_node', name='model_node', namespace=ns, output='screen',
             parameters=[config('hexapod_model', 'model_node.yaml'), robot]),
        Node(package='hexapod_locomotion', executable='locomotion_node', name='locomotion_node', namespace=ns,
             output='screen',
             parameters=[config('hexapod_locomotion', 'locomotion_node.yaml'), robot,
                         {'lockstep': lockstep, 'use_sim_time': lockstep}]),
    ])
