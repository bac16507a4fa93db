from setuptools import find_packages, setup

package_name = 'hexapod_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['data/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', ['config/sim_node.yaml']),   # --ros-args --params-file
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='hexapod maintainers',
    maintainer_email='hexapod@example.org',
    description='MuJoCo hexapod standing in for the hardware: same topics as the driver, terrain mockup, bag I/O and MCAP recording, replay, the stand calibration routine and the sim-vs-real discrepancy tool.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'replay = hexapod_sim.tools.replay:main',
            'reindex = hexapod_sim.bagio.reindex:main',
            'bench_replay = hexapod_sim.bench.bench_replay:main',
            'bench_kills = hexapod_sim.bench.kill_bench:main',
            'sim = hexapod_sim.node.cli:main',
            'sim_node = hexapod_sim.node.sim_node:main',
            'bench_sim = hexapod_sim.bench.bench_sim:main',
            'discrepancy = hexapod_sim.discrepancy.cli:main',
            'stand_calibration = hexapod_sim.calibration.stand:main',
            'record_contract = hexapod_sim.bagio.record_contract:main',
            'tf_figure = hexapod_sim.tools.tf_figure:main',
        ],
        # The MuJoCo hexapod as a backend of the driver's bus emulator (bus_emulator --backend sim).
        'hexapod_driver.emulator_backends': [
            'sim = hexapod_sim.node.emulator_backend:SimBackend',
        ],
    },
)
