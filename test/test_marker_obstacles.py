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

"""Sphere obstacles from visualization_msgs/MarkerArray: RViz's bookkeeping and the refusals."""

import math

import pytest
from toc_ros.conversions import ConversionError
from toc_ros.marker_obstacles import MarkerObstacles
from visualization_msgs.msg import Marker, MarkerArray

BASE = 'panda_link0'


def _marker(ns='obstacles', marker_id=0, action=Marker.ADD, xyz=(0.5, 0.0, 0.4),
            diameter=0.2, frame=BASE, marker_type=Marker.SPHERE, scale=None):
    marker = Marker(ns=ns, id=marker_id, action=action, type=marker_type)
    marker.header.frame_id = frame
    marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = xyz
    marker.scale.x, marker.scale.y, marker.scale.z = scale or (diameter,) * 3
    return marker


def _array(*markers):
    return MarkerArray(markers=list(markers))


def test_the_constants_are_visualization_msgs():
    from toc_ros import marker_obstacles as mo
    assert (mo.SPHERE, mo.ADD, mo.DELETE, mo.DELETEALL) == \
        (Marker.SPHERE, Marker.ADD, Marker.DELETE, Marker.DELETEALL)
    assert Marker.MODIFY == Marker.ADD


def test_add_replace_delete_deleteall():
    obstacles = MarkerObstacles(BASE)
    rows = obstacles.apply(_array(_marker(marker_id=1, xyz=(0.5, 0.1, 0.3), diameter=0.2),
                                  _marker(marker_id=0, xyz=(0.4, -0.2, 0.6), diameter=0.1)))
    assert rows == ((0.4, -0.2, 0.6, 0.05), (0.5, 0.1, 0.3, 0.1))
    # The same (ns, id) replaces; another ns with the same id is another obstacle.
    rows = obstacles.apply(_array(_marker(marker_id=1, xyz=(0.6, 0.0, 0.3), diameter=0.3),
                                  _marker(ns='boxes', marker_id=1, diameter=0.1)))
    assert rows == ((0.5, 0.0, 0.4, 0.05), (0.4, -0.2, 0.6, 0.05), (0.6, 0.0, 0.3, 0.15))
    rows = obstacles.apply(_array(_marker(marker_id=0, action=Marker.DELETE),
                                  _marker(marker_id=7, action=Marker.DELETE)))   # absent: no-op
    assert rows == ((0.5, 0.0, 0.4, 0.05), (0.6, 0.0, 0.3, 0.15))
    # DELETEALL, then an ADD in the same array.
    rows = obstacles.apply(_array(_marker(action=Marker.DELETEALL),
                                  _marker(marker_id=3, xyz=(0.0, 0.5, 0.5), diameter=0.4)))
    assert rows == ((0.0, 0.5, 0.5, 0.2),) == obstacles.rows
    assert obstacles.apply(_array(_marker(action=Marker.DELETEALL))) == ()


def test_leading_slash_of_the_frame_is_the_same_frame():
    assert MarkerObstacles('/' + BASE).apply(_array(_marker()))[0][3] == 0.1


@pytest.mark.parametrize('marker, reason', [
    (_marker(marker_type=Marker.CUBE), 'is not SPHERE'),
    (_marker(scale=(0.2, 0.2, 0.3)), 'non-uniform scale'),
    (_marker(scale=(0.0, 0.0, 0.0)), 'must be positive'),
    (_marker(scale=(-0.2, -0.2, -0.2)), 'must be positive'),
    (_marker(frame='world'), "is not the base frame 'panda_link0'"),
    (_marker(frame=''), 'is not the base frame'),
    (_marker(xyz=(math.nan, 0.0, 0.0)), 'NaN or infinite'),
    (_marker(diameter=math.inf), 'NaN or infinite'),
    (_marker(action=5), 'unknown action 5'),
])
def test_refusals_name_the_marker_and_leave_the_set_unchanged(marker, reason):
    obstacles = MarkerObstacles(BASE)
    before = obstacles.apply(_array(_marker(marker_id=9)))
    with pytest.raises(ConversionError, match=reason) as info:
        obstacles.apply(_array(_marker(marker_id=4, xyz=(0.1, 0.1, 0.1)), marker))
    assert "marker 'obstacles'/" in str(info.value)
    assert obstacles.rows == before
