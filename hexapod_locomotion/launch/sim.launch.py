"""The simulated robot: the MuJoCo hexapod with the driver's interface (sim_node),
/predict_swing_down (model_node) and Algorithm 1 driven by cmd_vel (locomotion_node).

    ros2 launch hexapod_locomotion sim.launch.py [namespace:=hexa] [terrain:=mockup]
        [robot_overlays:="['/path/my_robot.yaml']"] [route:=composed|processes|lockstep]

route:=composed (the default) runs the three nodes in one process, ``hexapod_locomotion robot``,
in real time with Algorithm 1's cadence. route:=processes runs them as three processes over DDS in
real time, which on a small machine cannot hold that cadence; route:=lockstep runs the three
processes in deterministic lock-step (the sim advances one read cycle per command, in simulated
time). docs/architecture.md has the measurements. Each node loads its package's
config/<executable>.yaml (every parameter at its default: copy and edit one, or override here).
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
    terrain = {'terrain': LaunchConfiguration('terrain')}
    lockstep = PythonExpression(["'", LaunchConfiguration('route'), "' == 'lockstep'"])
    is_composed = PythonExpression(["'", LaunchConfiguration('route'), "' == 'composed'"])
    composed, processes = IfCondition(is_composed), UnlessCondition(is_composed)
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='', description='namespace of every topic and service'),
        DeclareLaunchArgument('robot_description', default_value='',
                              description="robot description YAML ('' = the packaged robot.yaml)"),
        DeclareLaunchArgument('robot_overlays', default_value="['']",
                              description='overlay YAMLs merged over the description, as a YAML list'),
        DeclareLaunchArgument('terrain', default_value='mockup', description='flat, blocks, stairs, rough, mockup'),
        DeclareLaunchArgument('route', default_value='composed', choices=['composed', 'processes', 'lockstep'],
                              description='composed: one process in real time; processes: three over DDS in real '
                                          'time; lockstep: three over DDS, deterministic, in simulated time'),
        Node(package='hexapod_locomotion', executable='robot', namespace=ns, output='screen', condition=composed,
             parameters=[config('hexapod_sim', 'sim_node.yaml'), config('hexapod_model', 'model_node.yaml'),
                         config('hexapod_locomotion', 'locomotion_node.yaml'), robot, terrain,
                         {'hardware': 'sim'}]),
        Node(package='hexapod_sim', executable='sim_node', name='sim_node', namespace=ns, output='screen',
             condition=processes,
             parameters=[config('hexapod_sim', 'sim_node.yaml'), robot, terrain, {'lockstep': lockstep}]),
        Node(package='hexapod_model', executable='model_node', name='model_node', namespace=ns, output='screen',
             condition=processes, parameters=[config('hexapod_model', 'model_node.yaml'), robot]),
        Node(package='hexapod_locomotion', executable='locomotion_node', name='locomotion_node', namespace=ns,
             output='screen', condition=processes,
             parameters=[config('hexapod_locomotion', 'locomotion_node.yaml'), robot,
                         {'lockstep': lockstep, 'use_sim_time': lockstep}]),
    ])
