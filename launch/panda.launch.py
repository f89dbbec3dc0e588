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
The Panda: solver_node plans for it, plant_node simulates it on MuJoCo, recorder_node records.

    ros2 launch toc_ros panda.launch.py [execute:=action] [command_interface:=position]
        [namespace:=ns] [record:=false] [output:=runs/x] [params_file:=my_panda.yaml]

robot_description is example-robot-data's Panda URDF (both nodes get it as a parameter).
execute:=action sends every plan through the plant's FollowJointTrajectory server, as to a
ros2_control JointTrajectoryController (needs control_msgs); the solver's trajectory topic is
then remapped to planned_trajectory so that the plant hears each plan once.
command_interface:=position makes the plant a position-controlled arm (its drives track the
commanded positions with gravity compensation, no torque feed-forward, and its controller
refuses goals with efforts, as JointTrajectoryController does): the solver then sends goals
without efforts (execute.effort false).  Send a goal with
    ros2 topic pub --once -w 2 --keep-alive 1 goal_joints sensor_msgs/msg/JointState "{name: [
        panda_joint1, panda_joint2, panda_joint3, panda_joint4, panda_joint5, panda_joint6,
        panda_joint7],
        position: [0.8, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785]}"
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.conditions import UnlessCondition
from launch.substitutions import AndSubstitution
from launch.substitutions import EqualsSubstitution
from launch.substitutions import LaunchConfiguration
from launch.substitutions import NotEqualsSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from toc_ros.core.arms.model import named_arm_path

ACTION = 'follow_joint_trajectory'


def generate_launch_description():
    share = get_package_share_directory('toc_ros')
    with open(named_arm_path('panda')) as stream:
        urdf = stream.read()

    params_file = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    record = LaunchConfiguration('record')
    output = LaunchConfiguration('output')
    execute = LaunchConfiguration('execute')
    through_action = EqualsSubstitution(execute, 'action')
    command_interface = LaunchConfiguration('command_interface')

    arguments = [
        DeclareLaunchArgument(
            'params_file', default_value=os.path.join(share, 'config', 'panda.yaml'),
            description='ROS parameters of solver_node and plant_node for the Panda'),
        DeclareLaunchArgument(
            'execute', default_value='topic', choices=['topic', 'action'],
            description='topic: the plant follows the trajectory topic; action: every plan '
                        "goes through the plant's FollowJointTrajectory server"),
        DeclareLaunchArgument(
            'command_interface', default_value='effort', choices=['effort', 'position'],
            description="the plant's drives (plant_node command_interface): effort (torques, "
                        'the plan fed forward) or position (a position-controlled arm; goals '
                        'then carry no efforts)'),
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
    ]

    common = {'package': 'toc_ros', 'namespace': namespace, 'output': 'screen',
              'emulate_tty': True}
    description = {'robot_description': ParameterValue(urdf, value_type=str)}
    # The action is the plant's own server, resolved in the launch namespace.
    action_of_plant = 'plant_node/' + ACTION
    solver_topic = Node(
        executable='solver_node', name='solver_node', parameters=[params_file, description],
        condition=UnlessCondition(through_action), **common)
    solver_action = Node(
        executable='solver_node', name='solver_node',
        parameters=[params_file, description,
                    {'execute.follow_joint_trajectory': ParameterValue(action_of_plant,
                                                                       value_type=str),
                     # Efforts only for a controller with an effort command interface.
                     'execute.effort': ParameterValue(
                         EqualsSubstitution(command_interface, 'effort'), value_type=bool)}],
        remappings=[('trajectory', 'planned_trajectory')],
        condition=IfCondition(through_action), **common)
    plant = Node(executable='plant_node', name='plant_node',
                 parameters=[params_file, description,
                             {'command_interface': command_interface}], **common)
    recorder_to_output = Node(
        executable='recorder_node', name='recorder_node',
        parameters=[{'output': ParameterValue(output, value_type=str)}],
        condition=IfCondition(AndSubstitution(record, NotEqualsSubstitution(output, ''))),
        **common)
    recorder_default = Node(
        executable='recorder_node', name='recorder_node',
        condition=IfCondition(AndSubstitution(record, EqualsSubstitution(output, ''))),
        **common)
    return LaunchDescription(arguments + [recorder_to_output, recorder_default, solver_topic,
                                          solver_action, plant])
