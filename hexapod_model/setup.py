from setuptools import find_packages, setup

package_name = 'hexapod_model'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['data/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', ['config/model_node.yaml', 'config/robot_state.yaml']),   # --ros-args --params-file
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='hexapod maintainers',
    maintainer_email='hexapod@example.org',
    description='Robot description, kinematics, body leveling, the AX-12A servo law, the swing-down dynamic model of leg + servo controller (Faigl & Cizek Eq. 11-17), the ROS contract, the ServoBus interface and the model node.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'model_node = hexapod_model.model_node:main',
            'robot_state = hexapod_model.robot_state:main',
            'bench_model = hexapod_model.bench_model:main',
        ],
    },
)
