# Copyright 2026 toc_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Closed-loop demo: solver_node, plant_node and (optionally) recorder_node.

    ros2 launch toc_ros demo.launch.py [namespace:=ns] [record:=false] [output:=runs/x]
        [params_file:=my.yaml] [use_sim_time:=true]

Send a goal with e.g.
    ros2 topic pub --once -w 2 --keep-alive 1 goal_joints sensor_msgs/msg/JointState \
        "{name: [rotation_joint, extension_joint], position: [1.309, 1.0]}"
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import AndSubstitution
from launch.substitutions import EqualsSubstitution
from launch.substitutions import LaunchConfiguration
from launch.substitutions import NotEqualsSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    default_params = os.path.join(
        get_package_share_directory('toc_ros'), 'config', 'toc_ros.yaml')

    params_file = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    record = LaunchConfiguration('record')
    output = LaunchConfiguration('output')
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)

    arguments = [
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='ROS parameters file for all nodes (default: the paper scenario)'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='Namespace of all nodes and their (relative) topics'),
        DeclareLaunchArgument(
            'record', default_value='true',
            description='Start recorder_node to record every topic to an MCAP bag'),
        DeclareLaunchArgument(
            'output', default_value='',
            description="Bag directory of the recording (empty: the recorder's "
                        'default runs/<UTC timestamp>/)'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='Use /clock as time source in every node'),
    ]

    common = {
        'package': 'toc_ros',
        'namespace': namespace,
        'output': 'screen',
        'emulate_tty': True,
    }
    solver = Node(
        executable='solver_node', name='solver_node',
        parameters=[params_file, {'use_sim_time': use_sim_time}], **common)
    plant = Node(
        executable='plant_node', name='plant_node',
        parameters=[params_file, {'use_sim_time': use_sim_time}], **common)
    # Two variants so that an empty `output` leaves the recorder's own default (or a value
    # from params_file) in place instead of overriding it with ''.
    recorder_to_output = Node(
        executable='recorder_node', name='recorder_node',
        parameters=[params_file, {'use_sim_time': use_sim_time,
                                  'output': ParameterValue(output, value_type=str)}],
        condition=IfCondition(AndSubstitution(record, NotEqualsSubstitution(output, ''))),
        **common)
    recorder_default = Node(
        executable='recorder_node', name='recorder_node',
        parameters=[params_file, {'use_sim_time': use_sim_time}],
        condition=IfCondition(AndSubstitution(record, EqualsSubstitution(output, ''))),
        **common)

    # Recorder first: it then records from the start, and a bad `record`/`use_sim_time` value
    # fails launch before any process was started (none is left running).
    return LaunchDescription(arguments + [recorder_to_output, recorder_default, solver, plant])
