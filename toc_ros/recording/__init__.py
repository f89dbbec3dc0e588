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
Recording of ROS 2 topics into rosbag2 bag directories with MCAP storage.

``bag_writer`` writes a bag (rosbag2's QoS and YAML formats in ``bag_metadata``), ``bag_reader``
reads one back (also a cut-off one); neither they nor ``msg_definitions`` need rclpy (only
``Recording.decode`` does); ``bag_tool`` is the ``toc-bag`` command (info, recover). The
recorder node lives in ``toc_ros.nodes.recorder_node`` and ``process`` starts and stops it as a
separate process.
"""

from .bag_metadata import qos_profile_to_dict
from .bag_reader import RawMessage, Recording, TopicInfo
from .bag_writer import BagSummary, BagWriter, RecordingError
from .msg_definitions import full_definition, MessageDefinition, MessageDefinitionError
from .process import recorder_command, RecorderProcess

__all__ = [
    'BagSummary', 'BagWriter', 'full_definition', 'MessageDefinition',
    'MessageDefinitionError', 'qos_profile_to_dict', 'RawMessage', 'recorder_command',
    'RecorderProcess', 'Recording', 'RecordingError', 'TopicInfo',
]
