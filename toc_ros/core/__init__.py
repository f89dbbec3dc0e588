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

"""ROS-free numeric core of toc_ros: robot models, BPTT gradient, solvers, result types."""

from ._numba_cache import use_source_keyed_cache

use_source_keyed_cache()

# The imports below compile or load the numba kernels; the cache directory must be set first.

from .model import hand_position, RobotParams  # noqa: E402
from .models import CylindricalRobot, load_model, ModelError, MODELS, RobotModel  # noqa: E402, E501
from .obstacles import arm_clearance  # noqa: E402
from .problem import measure_violations, PaperOptions, Problem, ProblemError, SolverOptions  # noqa: E402, E501
from .result import Progress, SolveResult, Status, Violations  # noqa: E402
from .solver import solve, warm_up, warm_up_for  # noqa: E402

__all__ = [
    'arm_clearance', 'CylindricalRobot', 'hand_position', 'load_model', 'measure_violations',
    'ModelError', 'MODELS', 'PaperOptions', 'Problem', 'ProblemError', 'Progress', 'RobotModel',
    'RobotParams', 'SolveResult', 'SolverOptions', 'solve', 'Status', 'Violations', 'warm_up',
    'warm_up_for',
]
