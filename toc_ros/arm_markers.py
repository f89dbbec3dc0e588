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
solver_node's markers for a URDF arm (RViz): obstacle spheres, the arm's spheres, the tip path.

DELETEALL, then per obstacle a SPHERE (ns 'obstacles', diameter 2 r) and its inflated sphere
(ns 'inflated_obstacles', r + margin: what the plans keep the arm's spheres out of), the
planned tip path (ns 'planned_path', LINE_STRIP), the arm's collision spheres at the measured
state (ns 'arm', one SPHERE each) and the text markers 'obstacles_info' / 'plan_info' (the
obstacles hash and data revision, as for the planar models).
"""

from geometry_msgs.msg import Point
import numpy as np
from toc_ros import arm_config, progress as schema
from toc_ros.conversions import new_marker
from visualization_msgs.msg import Marker, MarkerArray


def _sphere(frame_id, stamp, ns, marker_id, centre, radius, rgba):
    marker = new_marker(frame_id, stamp, ns, marker_id, Marker.SPHERE, rgba)
    marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = (
        float(v) for v in centre)
    marker.scale.x = marker.scale.y = marker.scale.z = 2.0 * float(radius)
    return marker


def arm_markers(config, stamp, path_states, measured, plan_info, revision):
    """
    Return the MarkerArray of an arm configuration (solver_node's config).

    path_states: the executing plan's states (q, dq) or None; measured: the measured joint
    state (q1, dq1, ...) or None (then initial_state, when it is an arm state).
    """
    frame = config.frames.base_frame
    model = config.model
    rows = arm_config.obstacle_rows(config.flat)
    margin = config.problem.margin
    out = MarkerArray()
    clear = Marker()
    clear.header.frame_id = frame
    clear.header.stamp = stamp
    clear.action = Marker.DELETEALL
    out.markers.append(clear)
    for k, (x, y, z, r) in enumerate(rows):
        out.markers.append(_sphere(frame, stamp, 'obstacles', k, (x, y, z), r,
                                   (0.5, 0.5, 0.5, 0.8)))
        out.markers.append(_sphere(frame, stamp, 'inflated_obstacles', k, (x, y, z),
                                   r + margin, (1.0, 0.5, 0.0, 0.25)))
    if not model.pending:
        tip = arm_config.settings(config.flat).tip_link
        if path_states is not None and np.shape(path_states)[-1] == model.nx:
            line = new_marker(frame, stamp, 'planned_path', 0, Marker.LINE_STRIP,
                              (0.0, 0.8, 0.0, 1.0))
            line.scale.x = 0.01
            line.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))
                           for p in (pose.translation for pose in
                                     model.tip_poses(model.positions(path_states), tip))]
            out.markers.append(line)
        state = (model.full_state(measured) if measured is not None
                 and np.size(measured) == model.nx else
                 (config.problem.x0 if np.size(config.problem.x0) == model.nx else None))
        spheres = model.robot.spheres
        if state is not None and spheres is not None:
            from toc_ros.core.arms import sphere_centres
            centres = sphere_centres(model.arm, spheres, model.positions(state))
            for k, (centre, radius) in enumerate(zip(centres, spheres.radii)):
                out.markers.append(_sphere(frame, stamp, 'arm', k, centre, radius,
                                           (0.1, 0.3, 1.0, 0.6)))
    for ns, info, z, text in (
            ('obstacles_info', (schema.obstacles_hash(rows, margin), revision), 1.3,
             'obstacles'), ('plan_info', plan_info, 1.45, 'plan for obstacles')):
        if info is None:
            continue
        label = new_marker(frame, stamp, ns, 0, Marker.TEXT_VIEW_FACING, (1.0, 1.0, 1.0, 1.0))
        label.pose.position.z = z
        label.scale.z = 0.08
        label.text = f'{text} {info[0]}, data revision {info[1]}'
        out.markers.append(label)
    return out
