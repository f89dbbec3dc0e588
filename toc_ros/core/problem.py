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

"""Problem definition, solver options and input validation (before any iteration runs)."""

import dataclasses
from dataclasses import dataclass, field
import math
from typing import Optional, Tuple

import numpy as np

from .horizon import integrator_id
from .model import RobotParams
from .models.base import RobotModel
from .models.cylindrical import CylindricalRobot
from .obstacles import GRAD_EXACT, GRAD_SHORTCUT, model_clearance
from .result import Violations
from .settings import setting

PAPER_X0 = (math.pi / 12.0, 0.0, 1.0, 0.0)
PAPER_GOAL = (5.0 * math.pi / 12.0, 0.0, 1.0, 0.0)
MAX_INTERVALS = 200000
MODES = ('fast', 'paper')
# Iteration budgets: paper mode runs the paper's M = 30000 gradient iterations; fast mode counts
# interior-point (Newton-type) iterations over all its grids.
DEFAULT_ITERATIONS = {'paper': 30000, 'fast': 2000}


class ProblemError(ValueError):
    """Invalid problem or options; the message says what and why."""


@dataclass(frozen=True)
class Problem:
    """
    Move the robot from x0 to x_goal (rest or not) in minimum time around circles.

    obstacles: rows (cx, cy, R') [m] in the base frame; margin dR [m] inflates each to
    R = R' + dR (section 4.2).  N intervals of tau = t_f / N, t_f0 the initial final time.
    """

    x0: Tuple[float, ...] = setting(
        PAPER_X0, '[q1 rad, dq1 rad/s, q2 m, dq2 m/s]: start state while no joint_states '
        'arrived (plant: state at start-up and after ~/reset)', ros_name='initial_state')
    x_goal: Tuple[float, ...] = setting(
        PAPER_GOAL, '[q1 rad, dq1 rad/s, q2 m, dq2 m/s]: goal of the scenario file '
        '(toc-solve); the node plans to goals from goal_pose, goal_joints and ~/plan',
        ros_name='goal_state')
    obstacles: Tuple[Tuple[float, float, float], ...] = setting(
        ((1.0, 1.0, 0.2),), "obstacle circles (x, y, radius R' > 0): obstacles.x/.y/.radius "
        'have equal lengths; set them together (atomically) or publish on the obstacles topic',
        unit='m', columns=('x', 'y', 'radius'))
    margin: float = setting(0.01, "dR: clearance margin, the arm stays outside R' + dR",
                            unit='m', low=0.0, high=100.0, ros_name='obstacles.margin')
    robot: RobotParams = field(default_factory=RobotParams)
    n_intervals: int = setting(1000, 'number of time intervals of the trajectory', low=2,
                               high=MAX_INTERVALS, ros_name='solver.N')
    integrator: str = setting('euler', "discretisation of eq. (37): 'euler' (the paper's) or "
                              "'rk4'", choices=('euler', 'rk4'), ros_name='solver.integrator')
    t_f0: float = setting(2.5, 'initial guess of the final time (> 0)', unit='s', low=0.0,
                          high=1e4, ros_name='solver.t_f0')
    # Another robot model (models/): None = the cylindrical robot of eq. (37) with `robot`.
    model: Optional[RobotModel] = None

    @property
    def robot_model(self):
        """Return the RobotModel solved for (models/base.py)."""
        return CylindricalRobot(self.robot) if self.model is None else self.model

    def with_model(self, model):
        """
        Return this problem for another RobotModel (the cylindrical one as `robot` data).

        Joint states x0, x_goal (2 n entries) become the model's states (models with actuator
        states: the torques that hold the joints' velocities, see actuated.py).
        """
        states = {name: _model_state(model, getattr(self, name)) for name in ('x0', 'x_goal')}
        if isinstance(model, CylindricalRobot):
            if model.params == self.robot and self.model is None:
                return dataclasses.replace(self, **states)
            return dataclasses.replace(self, robot=model.params, model=None, **states)
        return dataclasses.replace(self, model=model, **states)

    @property
    def integrator_id(self):
        """Kernel id of the integrator (ValueError when unknown)."""
        return integrator_id(self.integrator)

    def circles(self):
        """Obstacles as a (K, 3) array with inflated radii R = R' + dR."""
        c = np.array(self.obstacles, dtype=float).reshape(-1, 3)
        c[:, 2] += self.margin
        return c

    def kernel_arrays(self):
        """Return the kernels' inputs: packed robot data, x0, x_goal, u_max, inflated circles."""
        return (self.robot.packed(), np.asarray(self.x0, float), np.asarray(self.x_goal, float),
                self.robot.u_max, np.ascontiguousarray(self.circles()))

    def validate(self, states=True):
        """
        Raise ProblemError with every problem found (nothing is solved before this passes).

        states=False skips the checks of x0 and x_goal against the arm length and the
        obstacles (a node checks those per request, against the measured start).
        """
        if self.model is None and not isinstance(self.robot, RobotParams):
            raise ProblemError('robot must be a toc_ros.core.RobotParams')
        if self.model is not None and not isinstance(self.model, RobotModel):
            raise ProblemError('model must be a toc_ros.core.models.RobotModel')
        model = self.robot_model
        errors = list(model.check())
        x0 = _vector('x0', self.x0, model.nx, errors)
        xg = _vector('x_goal', self.x_goal, model.nx, errors)
        if not isinstance(self.n_intervals, (int, np.integer)) or isinstance(
                self.n_intervals, bool) or not 2 <= self.n_intervals <= MAX_INTERVALS:
            errors.append(f'N must be an integer in [2, {MAX_INTERVALS}], '
                          f'got {self.n_intervals!r}')
        try:
            integrator_id(self.integrator)
        except ValueError as exc:
            errors.append(str(exc))
        if not _finite_number(self.t_f0) or self.t_f0 <= 0.0:
            errors.append(f't_f0 must be a finite positive time [s], got {self.t_f0!r}')
        if not _finite_number(self.margin) or self.margin < 0.0:
            errors.append(f'margin must be finite and >= 0 [m], got {self.margin!r}')
        circles = None
        try:
            circles = np.array(self.obstacles, dtype=float).reshape(-1, 3)
        except (TypeError, ValueError):
            errors.append('obstacles must be rows (x, y, radius) of numbers')
        if circles is not None:
            for k, (cx, cy, radius) in enumerate(circles):
                if not all(map(math.isfinite, (cx, cy, radius))):
                    errors.append(f'obstacle {k} has a non-finite value ({cx}, {cy}, {radius})')
                elif radius <= 0.0:
                    errors.append(f'obstacle {k} radius must be > 0, got {radius}')
                elif _finite_number(self.margin) and math.hypot(cx, cy) <= radius + self.margin:
                    errors.append(f'obstacle {k} at ({cx}, {cy}) with inflated radius '
                                  f'{radius + self.margin} contains the robot base')
        if not errors and states:
            for name, x in (('start', x0), ('goal', xg)):
                errors += model.check_state(x, name)
            if not errors and len(circles):
                n_circles = len(circles)
                for name, x in (('start', x0), ('goal', xg)):
                    gaps = model_clearance(model, x[None, :], self.circles())[0]
                    for j in np.flatnonzero(gaps < 0.0):
                        link, k = divmod(int(j), n_circles)
                        where = f' (link {link})' if model.n_links > 1 else ''
                        errors.append(f'{name} state puts the arm{where} inside obstacle {k} '
                                      f'(inflated by the margin): clearance {gaps[j]:.6g} m')
        if errors:
            raise ProblemError('; '.join(errors))


@dataclass(frozen=True)
class PaperOptions:
    """Constants of the section-3 heuristic (defaults: the paper's section 4 values)."""

    k_b: float = setting(600.0, 'K_B of eq. (7), paper mode (> 0)', low=0.0, high=1e12,
                         ros_name='K_B')
    # J2 uses K_V-hat = tau0 K_V (section 4, constant tau0).
    k_v: float = setting(0.01, 'K_V, paper mode (> 0)', low=0.0, high=1e12, ros_name='K_V')
    k_p: float = setting(1000.0, 'K_p of eq. (42), obstacle penalty, paper mode (> 0)',
                         low=0.0, high=1e12, ros_name='K_p')
    eta: float = setting(1000.0, 'learning rate eta of eq. (32), paper mode (> 0)', low=0.0,
                         high=1e12)
    d_tau: float = setting(1e-5, 'decrement of tau = t_f / N of eq. (34), paper mode (> 0)',
                           unit='s', low=0.0, high=1.0)
    j_eps: float = setting(0.01, 'J_eps of eq. (34), paper mode (> 0)', low=0.0, high=1e12,
                           ros_name='J_eps')
    obstacle_gradient: str = setting('shortcut', "'shortcut' (eq. 46) or 'exact' (eqs. 44-45)",
                                     choices=('shortcut', 'exact'))

    def grad_mode(self):
        """Kernel id of the obstacle-gradient variant."""
        return GRAD_SHORTCUT if self.obstacle_gradient == 'shortcut' else GRAD_EXACT


@dataclass(frozen=True)
class SolverOptions:
    """How to solve: mode, iteration and time limits, progress period."""

    mode: str = setting('fast', "'fast' (feasible minimum time) or 'paper' (the section-3 "
                        'heuristic)', choices=MODES)
    # None: the mode's default (DEFAULT_ITERATIONS)
    max_iterations: Optional[int] = setting(
        None, "iteration limit of one solve; 0 = the mode's default (paper: M = 30000 gradient "
        'steps, fast: 2000 interior-point iterations)', low=0, high=1_000_000_000, none_value=0)
    # [s] wall clock; None = no limit (the nodes and the scenario file default to 60 s)
    timeout: Optional[float] = setting(None, 'wall-clock limit of one solve; 0 = none',
                                       unit='s', low=0.0, high=86400.0, none_value=0.0,
                                       ros_default=60.0)
    progress_period: float = 0.1         # [s] between progress callbacks
    paper: PaperOptions = field(default_factory=PaperOptions)

    def iteration_limit(self):
        """Return max_iterations, or the mode's default: the paper's M, or the fast budget."""
        if self.max_iterations is not None:
            return int(self.max_iterations)
        return DEFAULT_ITERATIONS[self.mode]

    def validate(self):
        """Raise ProblemError for bad option values."""
        errors = []
        if self.mode not in MODES:
            errors.append(f'mode must be one of {MODES}, got {self.mode!r}')
        if self.max_iterations is not None and (not isinstance(
                self.max_iterations, (int, np.integer)) or isinstance(
                self.max_iterations, bool) or self.max_iterations < 1):
            errors.append(f'max_iterations must be an integer >= 1, got {self.max_iterations!r}')
        if self.timeout is not None and (not _finite_number(self.timeout) or self.timeout <= 0):
            errors.append(f'timeout must be a positive number of seconds, got {self.timeout!r}')
        if not _finite_number(self.progress_period) or self.progress_period <= 0:
            errors.append(f'progress_period must be > 0, got {self.progress_period!r}')
        po = self.paper
        for name in ('k_b', 'k_v', 'k_p', 'eta', 'd_tau', 'j_eps'):
            value = getattr(po, name)
            if not _finite_number(value) or value <= 0.0:
                errors.append(f'paper.{name} must be a finite positive number, got {value!r}')
        if po.obstacle_gradient not in ('shortcut', 'exact'):
            errors.append("paper.obstacle_gradient must be 'shortcut' or 'exact', "
                          f'got {po.obstacle_gradient!r}')
        if errors:
            raise ProblemError('; '.join(errors))


def measure_violations(problem, controls, final_time):
    """Re-integrate controls over final_time and measure bounds, terminal error, clearance."""
    model = problem.robot_model
    controls = np.ascontiguousarray(controls, dtype=float)
    n = controls.shape[0]
    states = np.empty((n + 1, model.nx))
    model.kernels.rollout(np.asarray(problem.x0, float), controls, final_time / n,
                          model.packed(), problem.integrator_id, states)
    excess = np.max(np.abs(controls) - np.asarray(model.u_max)[None, :])
    circles = problem.circles()
    clearance = (float(np.min(model_clearance(model, states, circles)))
                 if len(circles) else math.inf)
    return states, Violations(
        max_control_excess=max(float(excess), 0.0),
        terminal_error=float(np.linalg.norm(states[-1] - np.asarray(problem.x_goal, float))),
        min_clearance=clearance)


def _model_state(model, x):
    """Return x as the model's state when it is a joint state of a larger one, else x."""
    try:
        arr = np.array(x, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return x            # validate() reports it
    if model.nx == arr.shape[0] or arr.shape[0] != 2 * model.n_joints \
            or not np.all(np.isfinite(arr)):
        return x
    try:
        return tuple(float(v) for v in model.full_state(arr))
    except (ArithmeticError, ValueError) as exc:        # ModelError is a ValueError
        raise ProblemError(f'no actuator state for the joint state {arr.tolist()}: {exc}')


def _finite_number(value):
    return (isinstance(value, (int, float, np.floating, np.integer))
            and not isinstance(value, bool) and math.isfinite(value))


def _vector(name, value, size, errors):
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        errors.append(f'{name} must be {size} numbers')
        return np.full(size, np.nan)
    if arr.shape != (size,):
        errors.append(f'{name} must have {size} entries [q1, dq1, q2, dq2, ...], got '
                      f'{arr.shape[0]}')
        return np.full(size, np.nan)
    if not np.all(np.isfinite(arr)):
        errors.append(f'{name} contains NaN or inf: {arr.tolist()}')
    return arr
