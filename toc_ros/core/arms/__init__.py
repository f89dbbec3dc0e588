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
URDF arms (ROS-free): Pinocchio model and limits, collision spheres, inverse kinematics.

model.py loads an arm and its planned joints, spheres.py its collision spheres, clearances.py
their clearances to obstacle spheres and to each other (kernels.py: the same for many
configurations in one compiled call), ik.py end-effector pose goals, validate.py the checks of
start/goal states.
"""

from .clearances import (check_obstacles, Collision, obstacle_clearance,
                         obstacle_clearance_jacobian, obstacle_clearances_batch,
                         self_clearance, self_clearance_jacobian, self_clearances_batch,
                         sphere_centres, sphere_jacobians, sphere_kinematics_batch,
                         worst_collision)
from .ik import solve_ik
from .model import ArmError, ArmModel, load_arm, NAMED_ARMS
from .spheres import default_spheres, load_spheres, shipped_spheres_path, Spheres
from .validate import check_state

__all__ = ['ArmError', 'ArmModel', 'check_obstacles', 'check_state', 'Collision',
           'default_spheres', 'load_arm', 'load_spheres', 'NAMED_ARMS', 'obstacle_clearance',
           'obstacle_clearance_jacobian', 'obstacle_clearances_batch', 'self_clearance',
           'self_clearance_jacobian', 'self_clearances_batch', 'shipped_spheres_path',
           'solve_ik', 'sphere_centres', 'sphere_jacobians', 'sphere_kinematics_batch',
           'Spheres', 'worst_collision']
