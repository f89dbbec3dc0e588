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
solver_node's settings: checked as a flat candidate set, then built once as typed objects.

A candidate set of flat parameter values (names of toc_ros.config and SolverNodeSettings) is
checked by ``parameter_errors``; an accepted one becomes a ``SolverNodeConfig``: the node's own
settings (``parameters.SolverNodeSettings``), the frames, the model choice, the scenario's
problem data and the solver options as the core dataclasses, and the robot model, built once
per accepted change, so that the node reads typed fields instead of looking names up.
"""

from dataclasses import dataclass
from typing import Any, Dict, Optional

from toc_ros import arm_config, arm_record
from toc_ros.config import (Frames, model_choice, model_from_parameters,
                            options_from_parameters, problem_from_parameters)
from toc_ros.core import ModelError, ProblemError
from toc_ros.core.estimation import ParameterEstimator
from toc_ros.core.models import ModelChoice
from toc_ros.core.problem import Problem, SolverOptions
from toc_ros.core.settings import from_parameters
from toc_ros.nodes import parameters
from toc_ros.nodes.parameters import SolverNodeSettings

# Parameters a plan depends on beyond its goal: a change restarts the running solve and
# re-checks the executing trajectory.
PLANNING_PREFIXES = ('obstacles.', 'robot.', 'extension_limits')


@dataclass(frozen=True)
class SolverNodeConfig:
    """One accepted set of solver_node parameters as typed objects."""

    flat: Dict[str, Any]         # the flat values (the input of toc_ros.config's builders)
    node: SolverNodeSettings     # solver_node's own settings (replan.*, start_lead, ...)
    frames: Frames               # joint_names, base_frame
    robot: ModelChoice           # robot.model, robot.model_parameters, robot.actuator_lag
    problem: Problem             # the scenario's data as given: initial_state (x0), obstacles
    options: SolverOptions       # solver.*
    model: Any                   # the RobotModel planned for (with its actuator lag)
    # A loaded URDF arm: what rebuilds it from a recording (its files read with the model).
    arm: Optional[arm_record.ArmRecord] = None

    @classmethod
    def from_flat(cls, params):
        """Build the typed settings of a checked flat set (ProblemError if it is not valid)."""
        params = dict(params)
        try:
            node = from_parameters(SolverNodeSettings, params)
            frames = from_parameters(Frames, params)
            problem = (arm_config.arm_problem(params, strict=False) if arm_config.is_arm(params)
                       else from_parameters(Problem, params))
        except (TypeError, ValueError) as exc:
            raise ProblemError(str(exc))
        model = model_from_parameters(params)
        arm = (arm_record.arm_record(params, model)
               if getattr(model, 'is_arm', False) and not model.pending else None)
        return cls(flat=params, node=node, frames=frames, robot=model_choice(params),
                   problem=problem, options=options_from_parameters(params), model=model,
                   arm=arm)

    @property
    def replanning(self):
        """
        Tell whether replan cycles run while a plan executes (fast mode, rate > 0).

        URDF arms too: their cycles warm-start from the executing plan's remainder and its
        multipliers like the planar models' (always Euler, the arm solver's discretisation).
        """
        return self.node.replan_rate > 0.0 and self.options.mode == 'fast'

    @property
    def is_arm(self):
        """Tell whether the model is a URDF arm (robot.model panda, ur5 or urdf)."""
        return getattr(self.model, 'is_arm', False)

    def model_keys(self, texts=False):
        """
        Return the robot-model values of progress reports (what was planned for).

        URDF arms add their ArmRecord; texts (the ready report, once per model load): with
        the sphere file's and a parameter URDF's text, too large for every result.
        """
        keys = {'robot_model': self.robot.name,
                'model_parameters': ', '.join(self.robot.parameters)}
        if self.arm is not None:
            keys.update(self.arm.fields(texts))
        return keys

    def planning_data(self):
        """Return the parameter values a plan depends on beyond its goal."""
        return planning_data(self.flat)


def planning_data(params):
    """Return the flat values a plan depends on beyond its goal (one revision's data)."""
    data = {k: v for k, v in params.items()
            if k.startswith(PLANNING_PREFIXES) and k != 'obstacles.max_count'}
    if arm_config.is_arm(params):       # the URDF an arm model is built from, its joints
        data['robot_description'] = arm_config.effective_description(params)
        data['joint_names'] = tuple(params.get('joint_names', ()))
    return data


def parameter_errors(params):
    """
    Everything wrong with a candidate set of solver_node parameters (empty: valid).

    Whether start and goal states clear the obstacles is checked per request, against the
    measured start state, not here.
    """
    return checked(params)[0]


def checked(params):
    """Return (errors, the SolverNodeConfig of params or None) of a candidate set."""
    try:
        model = model_from_parameters(params)
    except ProblemError as exc:
        return [str(exc)], None
    if getattr(model, 'is_arm', False):
        return _checked_arm(params, model)
    errors = parameters.joint_name_errors(params['joint_names'], model.n_joints, model.name)
    if params['replan.estimate']:
        try:
            ParameterEstimator(model.joint_model, params['replan.estimate'],
                               float(params['replan.estimate_window']))
        except ModelError as exc:
            errors.append(f'replan.estimate: {exc}')
    if not str(params['base_frame']).strip('/'):
        errors.append('base_frame must not be empty')
    limit_errors = parameters.vector_errors('extension_limits', params['extension_limits'], 2)
    if not limit_errors and not params['extension_limits'][0] < params['extension_limits'][1]:
        limit_errors = [f'extension_limits must be [q2_min, q2_max] with q2_min < q2_max, got '
                        f'{params["extension_limits"]}']
    errors += limit_errors
    count, limit = len(params['obstacles.x']), int(params['obstacles.max_count'])
    if count > limit:
        errors.append(f'{count} obstacles exceed obstacles.max_count = {limit}')
        return errors, None     # no per-obstacle work on a refused set
    state_errors = (
        parameters.vector_errors('initial_state', params['initial_state'], 2 * model.n_joints)
        + parameters.vector_errors('goal_state', params['goal_state'], 2 * model.n_joints))
    errors += state_errors
    try:
        options_from_parameters(params).validate()
    except (ProblemError, TypeError, ValueError) as exc:
        errors.append(str(exc))
    if not state_errors:    # else the Problem would repeat them as x0 / x_goal errors
        try:
            # The one check of the problem data, obstacles included (start and goal against
            # the obstacles are checked per request, against the measured start).
            problem_from_parameters(params).validate(states=False)
        except (ProblemError, TypeError, ValueError) as exc:
            errors.append(str(exc))
    config = None
    if not errors:
        try:    # the typed settings of an accepted set must build
            config = SolverNodeConfig.from_flat(params)
        except (ProblemError, TypeError, ValueError) as exc:
            errors.append(str(exc))
    return errors, config


def _checked_arm(params, model):
    """Return (errors, the SolverNodeConfig or None) of a candidate set for a URDF arm."""
    errors = arm_config.arm_errors(params, model)
    try:
        options_from_parameters(params).validate()
    except (ProblemError, TypeError, ValueError) as exc:
        errors.append(str(exc))
    config = None
    if not errors:
        try:
            config = SolverNodeConfig.from_flat(params)
        except (ProblemError, TypeError, ValueError) as exc:
            errors.append(str(exc))
    return errors, config
