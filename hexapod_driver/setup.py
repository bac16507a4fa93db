from setuptools import find_packages, setup

package_name = 'hexapod_driver'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['data/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='hexapod maintainers',
    maintainer_email='hexapod@example.org',
    description='Dynamixel AX-12A bus (Protocol 1.0) exposed as ROS topics, with an emulated bus for testing without hardware.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'driver_node = hexapod_driver.driver_node:main',
            'bus_emulator = hexapod_driver.emulator:main',
            'bench_driver = hexapod_driver.bench_driver:main',
            'servo_tool = hexapod_driver.servo_tool:main',
            'stand_calibration = hexapod_driver.stand_calibration:main',
            'record_contract = hexapod_driver.record_contract:main',
        ],
    },
)
