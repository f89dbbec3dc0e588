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

"""toc_ros: minimum-time trajectories by backpropagation-through-time, on ROS 2."""

import os
import sys

__version__ = '0.1.0'

# In a plain venv with the ROS 2 wheels (no setup.bash sourced) the message packages live in
# sys.prefix/share: let the ament index find them there, for this process and its children.
if not os.environ.get('AMENT_PREFIX_PATH') and os.path.isdir(
        os.path.join(sys.prefix, 'share', 'ament_index')):
    os.environ['AMENT_PREFIX_PATH'] = sys.prefix
