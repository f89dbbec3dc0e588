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
Sphere obstacles from RViz-style markers (visualization_msgs/MarkerArray), ROS-message-level.

The set is kept the way RViz keeps markers: ADD (or the deprecated MODIFY, the same value)
puts the marker with its (ns, id), replacing one with the same key; DELETE removes that key;
DELETEALL clears everything (markers after it in the same array are applied afterwards).  An
obstacle is a SPHERE marker in the base frame with a uniform scale (the diameter).  Any other
marker type, a non-uniform or non-positive scale, another frame or a non-finite value refuses
the whole array with the reason and leaves the set as it was: a planner never plans around
half of an update.  Marker lifetimes are not honoured: an obstacle stays until it is deleted.
"""

import math

from toc_ros.conversions import ConversionError
from toc_ros.core.arms.clearances import check_obstacles
from toc_ros.core.arms.model import ArmError

# visualization_msgs/msg/Marker constants (kept here so that the rules read without ROS).
SPHERE = 2
ADD = 0
DELETE = 2
DELETEALL = 3
# Scales that differ by more than this relative amount are not one sphere.
SCALE_RTOL = 1e-6


def _key(marker):
    return (marker.ns, int(marker.id))


def _name(marker):
    return f'marker {marker.ns!r}/{marker.id}'


def _sphere(marker, base_frame):
    """Return (x, y, z, r) of an ADD marker, or raise ConversionError with the reason."""
    frame = marker.header.frame_id.lstrip('/')
    if frame != base_frame.lstrip('/'):
        raise ConversionError(f'{_name(marker)}: frame {marker.header.frame_id!r} is not the '
                              f'base frame {base_frame!r} (no tf lookup: publish obstacles in '
                              'the base frame)')
    if marker.type != SPHERE:
        raise ConversionError(f'{_name(marker)}: type {marker.type} is not SPHERE ({SPHERE}): '
                              'obstacles are spheres')
    scale = (marker.scale.x, marker.scale.y, marker.scale.z)
    position = (marker.pose.position.x, marker.pose.position.y, marker.pose.position.z)
    if not all(math.isfinite(v) for v in scale + position):
        raise ConversionError(f'{_name(marker)}: NaN or infinite position or scale '
                              f'{position}, {scale}')
    if min(scale) <= 0.0:
        raise ConversionError(f'{_name(marker)}: scale {scale} must be positive')
    if max(scale) - min(scale) > SCALE_RTOL * max(scale):
        raise ConversionError(f'{_name(marker)}: non-uniform scale {scale}: a sphere obstacle '
                              'has one diameter')
    return position + (0.5 * scale[0],)


class MarkerObstacles:
    """The sphere obstacles of the markers received so far; apply() one MarkerArray at a time."""

    def __init__(self, base_frame):
        self.base_frame = base_frame
        self._spheres = {}          # (ns, id) -> (x, y, z, r)

    @property
    def rows(self):
        """Return the obstacle rows: (x, y, z, r) [m] ordered by (ns, id)."""
        return tuple(self._spheres[key] for key in sorted(self._spheres))

    def apply(self, msg, max_count=None):
        """
        Apply a MarkerArray; return the new rows, or raise ConversionError (set unchanged).

        An unknown action is refused as well, and so is a set of more than max_count spheres
        (None: no limit).
        """
        spheres = dict(self._spheres)
        for marker in msg.markers:
            if marker.action == DELETEALL:
                spheres.clear()
            elif marker.action == DELETE:
                spheres.pop(_key(marker), None)
            elif marker.action == ADD:
                spheres[_key(marker)] = _sphere(marker, self.base_frame)
            else:
                raise ConversionError(f'{_name(marker)}: unknown action {marker.action}')
        if max_count is not None and len(spheres) > max_count:
            raise ConversionError(f'{len(spheres)} obstacles exceed obstacles.max_count = '
                                  f'{max_count}')
        rows = tuple(spheres[key] for key in sorted(spheres))
        try:
            check_obstacles(rows)    # the arms' one obstacle check (finite, radius >= 0)
        except ArmError as exc:
            raise ConversionError(str(exc)) from None
        self._spheres = spheres
        return rows

    def clear(self):
        """Forget every marker (the obstacle set was replaced another way)."""
        self._spheres = {}
