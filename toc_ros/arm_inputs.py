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
The topic inputs of a URDF arm as flat values: obstacle spheres and the robot_description.

Each input becomes (flat key, value) for the node to apply as it applies a parameter change
(toc_ros.arm_config: ``obstacles.spheres``, ``robot_description.topic``), or a
ConversionError with the reason (reported on ~/progress, nothing changes):

- ``obstacle_markers`` (visualization_msgs/MarkerArray): the marker set kept as RViz keeps it
  (toc_ros.marker_obstacles), SPHERE markers in base_frame;
- ``obstacles`` (std_msgs/Float64MultiArray): rows (x, y, z, r) that replace the set (and
  forget the markers: the newest message of either topic gives the whole set);
- ``robot_description`` (std_msgs/String): the URDF, used by robot.model urdf while the
  robot_description parameter is empty.
"""

import numpy as np

from toc_ros import arm_config
from toc_ros.conversions import ConversionError
from toc_ros.marker_obstacles import MarkerObstacles

COLUMNS = 4     # x, y, z, r


def _require_arm(config, topic):
    if not arm_config.is_arm(config.flat):
        raise ConversionError(f'{topic}: sphere obstacles need a URDF arm (robot.model panda, '
                              f'ur5 or urdf), robot.model is {config.robot.name!r}')


def sphere_count(msg):
    """Rows of a Float64MultiArray of spheres, counted without reading the data."""
    dims = list(msg.layout.dim)
    if dims:
        return int(dims[0].size)
    return len(msg.data) // COLUMNS


def sphere_rows(msg):
    """
    Return the rows (x, y, z, r) of a Float64MultiArray (ConversionError for a bad one).

    The layout may be empty (data holds whole rows) or (rows, 4); data_offset is honoured;
    values must be finite, radii >= 0.
    """
    dims = list(msg.layout.dim)
    data = np.asarray(msg.data, dtype=float)[int(msg.layout.data_offset):]
    if dims:
        if len(dims) != 2 or dims[1].size != COLUMNS:
            raise ConversionError('obstacles layout must be 2-D (rows, 4) for a URDF arm or '
                                  'empty, got ' + str([(d.label, d.size) for d in dims]))
        rows = dims[0].size
        if data.size < COLUMNS * rows or dims[0].stride not in (0, COLUMNS * rows):
            raise ConversionError(f'obstacles layout does not match the data: {rows} rows of '
                                  f'4 need {COLUMNS * rows} values, got {data.size}')
        data = data[:COLUMNS * rows]
    elif data.size % COLUMNS:
        raise ConversionError(f'obstacles data must hold rows of (x, y, z, radius) for a URDF '
                              f'arm: {data.size} values is not a multiple of 4')
    rows = data.reshape(-1, COLUMNS)
    from toc_ros.core.arms import ArmError, check_obstacles
    try:
        check_obstacles(rows)
    except ArmError as exc:
        raise ConversionError(str(exc)) from None
    return tuple(tuple(float(v) for v in row) for row in rows)


class ArmInputs:
    """Translates the arm's topic messages into flat values; keeps the marker set."""

    def __init__(self):
        self.markers = MarkerObstacles('')

    def from_markers(self, msg, config):
        """Return (key, rows) of an obstacle_markers MarkerArray (ConversionError)."""
        _require_arm(config, 'obstacle_markers')
        self.markers.base_frame = config.frames.base_frame
        rows = self.markers.apply(msg, config.node.max_count)
        return arm_config.SPHERES, rows

    def from_array(self, msg, config):
        """Return (key, rows) of an obstacles Float64MultiArray of spheres (ConversionError)."""
        _require_arm(config, 'obstacles')
        count, limit = sphere_count(msg), config.node.max_count
        if count > limit:       # refused before any per-obstacle work
            raise ConversionError(f'{count} obstacles exceed obstacles.max_count = {limit}')
        rows = sphere_rows(msg)
        self.markers.clear()
        return arm_config.SPHERES, rows

    @staticmethod
    def from_description(msg, config):
        """
        Return (key, URDF) of a robot_description message, or None when it is not used.

        None: the robot_description parameter is set (it wins) or the text is unchanged.
        """
        if str(config.flat.get('robot_description', '')).strip():
            return None
        if msg.data == config.flat.get(arm_config.TOPIC_DESCRIPTION):
            return None
        return arm_config.TOPIC_DESCRIPTION, msg.data
