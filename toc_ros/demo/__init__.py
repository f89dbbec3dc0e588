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
toc-demo: the closed-loop demo, solver_node + plant_node + recorder_node as separate processes.

On a private ROS domain (a random ROS_DOMAIN_ID unless one is set; localhost discovery) it
starts the three nodes, sends the paper's obstacle and goal (solver_node queues it while its
numba kernels load), lets the plant execute the minimum-time trajectory, then sends a second
goal with a changed obstacle set (the solver replans from the plant's measured state), stops
every process with SIGINT and prints a summary, also written to ``summary.json`` next to the
recording (default ``runs/<UTC timestamp>/``).

Exit code 0 when both plans were SOLVED, the plant came to rest within POSITION_TOL of each
goal and every process exited cleanly (so the recording is complete); 1 otherwise; 2 for bad
arguments; 130 when interrupted.

Modules: run (the stages, over toc_ros.harness), checks (acceptance), summary (the text and
the recording's facts), cli (arguments, signals, output files).
"""

from .cli import main

__all__ = ['main']
