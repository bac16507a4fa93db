from setuptools import find_packages, setup

package_name = 'hexapod_locomotion'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['data/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', ['config/locomotion_node.yaml', 'config/terrain_node.yaml', 'config/calibration_walk.yaml']),   # --ros-args --params-file
        ('share/' + package_name + '/launch', ['launch/robot.launch.py', 'launch/sim.launch.py']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='hexapod maintainers',
    maintainer_email='hexapod@example.org',
    description='Gaits, swing phases, Algorithm 1 adaptive ground detection and the fixed-threshold baseline, body leveling, the locomotion node and the paper\'s experiments.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'discrepancy_bench = hexapod_locomotion.bench.discrepancy_bench:main',
            'random_bench = hexapod_locomotion.bench.random_bench:main',
            'locomotion_node = hexapod_locomotion.nodes.locomotion_node:main',
            'robot = hexapod_locomotion.nodes.robot:main',
            'bench_graph = hexapod_locomotion.bench.bench_graph:main',
            'demo = hexapod_locomotion.trials.demo:main',
            'experiment = hexapod_locomotion.trials.experiments:main',
            'analyse = hexapod_locomotion.trials.analyse:main',
            'cmd_vel_pub = hexapod_locomotion.nodes.cmd_vel_pub:main',
            'teleop_keyboard = hexapod_locomotion.nodes.teleop_keyboard:main',
            'odometry_bench = hexapod_locomotion.bench.odometry_bench:main',
            'fuzz_inputs = hexapod_locomotion.bench.fuzz_inputs:main',
            'terrain = hexapod_locomotion.trials.terrain_cli:main',
            'terrain_node = hexapod_locomotion.nodes.terrain_node:main',
            'soak = hexapod_locomotion.bench.soak:main',
        ],
    },
)
