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
ROS-free parts of the simulated plant.

simulator: the simulated robot of plant_node (stepping, drives, trajectory scheduling,
tracking), in integer nanoseconds of simulated time.
model: what it integrates (the robot model with the mismatch knobs, or MuJoCo), reference:
the Hermite reference of a topic trajectory.
mujoco_arm: a URDF arm simulated by MuJoCo (torque motors, mismatch knobs).
follow_joint_trajectory: ros2_controllers JointTrajectoryController's semantics for the
control_msgs/action/FollowJointTrajectory action (validation, interpolation, tolerances,
result codes), independent of rclpy and of control_msgs.
"""
