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
One minimum-time problem of a URDF arm, checked, with its CasADi model and numeric helpers.

The problem is the one toc_ros solves, written with the rigid-body recursions of arm_casadi.py
(independent of Pinocchio); arm_reference.py transcribes it for IPOPT and FATROP:

* state x = (q, qd), positions first; controls u = joint torques, constant on each of N
  intervals of h = t_f / N; t_f free; minimise t_f;
* x(0) = start, x(N) = goal (goal velocity 0 unless given);
* at every node k: lower <= q <= upper (continuous joints: no bound), |qd| <= velocity;
  |u| <= effort on every interval;
* for every robot sphere s (centre p_s(q) on its link, radius r_s) and obstacle sphere o
  (centre c_o, radius R_o), with R = r_s + R_o + margin: the clearance |p_s(q) - c_o| - R >= 0.

x(0) and x(N) are given: their limits and clearances are checked here, and a start or goal
that violates one is refused with the reason (SpecError).
"""

import dataclasses
import math
from typing import Mapping, Tuple, Union

import numpy as np
import yaml

from .arm_casadi import ArmCasadi
from .urdf_tree import GRAVITY, parse_urdf, sphere_points, UrdfError


class SpecError(ValueError):
    """The arm problem cannot be set up; the message says why."""


@dataclasses.dataclass(frozen=True)
class ArmSpec:
    """
    One arm problem, self-contained.

    urdf: file path or XML text; joints: planned joint names (their order is the order of q);
    start/goal: q (n values, velocity 0) or (q, qd) (2 n values); locked: {joint: value} for
    the joints not planned (default 0 clamped into their limits); obstacles: rows
    (cx, cy, cz, R) in the base frame [m]; robot_spheres: {link: [[x, y, z, r], ...]} in the
    link frames, or a YAML file of that mapping; margin [m]; limits: per-joint overrides
    {joint: {'lower'|'upper'|'effort'|'velocity': value}}; gravity in the base frame.
    """

    urdf: str
    joints: Tuple[str, ...]
    start: Tuple[float, ...]
    goal: Tuple[float, ...]
    locked: Mapping[str, float] = dataclasses.field(default_factory=dict)
    obstacles: Tuple[Tuple[float, float, float, float], ...] = ()
    robot_spheres: Union[None, str, Mapping] = None
    margin: float = 0.0
    limits: Mapping[str, Mapping[str, float]] = dataclasses.field(default_factory=dict)
    gravity: Tuple[float, float, float] = GRAVITY


def load_spheres(robot_spheres):
    """{link: [[x, y, z, r], ...]} from a mapping, a YAML file path or None."""
    if robot_spheres is None:
        return {}
    if isinstance(robot_spheres, (str, bytes)) or hasattr(robot_spheres, '__fspath__'):
        try:
            with open(robot_spheres, encoding='utf-8') as stream:
                data = yaml.safe_load(stream)
        except (OSError, yaml.YAMLError) as exc:
            raise SpecError(f'sphere file {robot_spheres}: {exc}') from None
    else:
        data = robot_spheres
    if not isinstance(data, Mapping):
        raise SpecError('robot spheres must map link names to lists [[x, y, z, r], ...]')
    return {str(k): [list(row) for row in v] for k, v in data.items()}


def _state(values, n, what):
    x = np.asarray(values, dtype=float).ravel()
    if x.size == n:
        x = np.concatenate([x, np.zeros(n)])
    if x.size != 2 * n or not np.all(np.isfinite(x)):
        raise SpecError(f'{what} must be {n} joint positions or {2 * n} positions and '
                        f'velocities, finite; got {np.asarray(values).tolist()}')
    return x


class ArmProblem:
    """
    A checked ArmSpec with its CasADi model, limits, spheres and numeric helpers.

    SpecError (a ValueError) with the reason for anything unusable: URDF, names, sphere data,
    obstacles, a start or goal outside the limits or in collision (pair and depth).
    """

    def __init__(self, spec, dynamics='aba'):
        self.spec = spec
        try:
            self.tree = parse_urdf(spec.urdf, spec.joints, spec.locked, spec.limits, spec.gravity)
            self.model = ArmCasadi(self.tree)
            spheres = load_spheres(spec.robot_spheres)
            points, radii = sphere_points(spheres)
            self.points = self.model.point_positions(points)
        except UrdfError as exc:
            raise SpecError(str(exc)) from None
        self.sphere_names = [f'{link}[{i}]' for link, rows in spheres.items()
                             for i in range(len(rows))]
        self.radii = radii
        self.n = n = self.tree.nq
        self.lower, self.upper, self.effort, self.velocity = self.tree.limits()
        try:
            obstacles = np.asarray(spec.obstacles, dtype=float).reshape(-1, 4) if len(
                spec.obstacles) else np.zeros((0, 4))
        except (TypeError, ValueError):
            obstacles = np.full((1, 4), np.nan)
        if not np.all(np.isfinite(obstacles)) or np.any(obstacles[:, 3] < 0.0):
            raise SpecError('obstacles must be rows (cx, cy, cz, R) of finite numbers, R >= 0')
        if not (math.isfinite(spec.margin) and spec.margin >= 0.0):
            raise SpecError(f'margin must be finite and >= 0, got {spec.margin!r}')
        self.obstacles = obstacles
        if obstacles.shape[0] and not radii.size:
            raise SpecError('obstacles need robot spheres (robot_spheres is empty)')
        # (sphere, obstacle) pairs, sphere-major; inflated radius R = r_s + R_o + margin.
        self.pair_radius = (radii[:, None] + obstacles[None, :, 3] + spec.margin).ravel()
        if np.any(self.pair_radius <= 0.0):
            raise SpecError('a sphere pair has r_s + R_o + margin = 0: give a radius or margin')
        self.n_pairs = self.pair_radius.size
        self.x0 = _state(spec.start, n, 'start')
        self.xg = _state(spec.goal, n, 'goal')
        self.f = self.model.state_derivative(dynamics)
        for name, x in (('start', self.x0), ('goal', self.xg)):
            self._check_node(x, name)

    # Numeric helpers (the CasADi model evaluated) ---------------------------------------------
    def clearance(self, q):
        """Distance minus inflated radius of every (sphere, obstacle) pair at q, (S * O,)."""
        if not self.n_pairs:
            return np.zeros(0)
        p = np.asarray(self.points(np.asarray(q, dtype=float))).reshape(3, -1)
        d = np.linalg.norm(p.T[:, None, :] - self.obstacles[None, :, :3], axis=2)
        return d.ravel() - self.pair_radius

    def _check_node(self, x, name):
        q, qd = x[:self.n], x[self.n:]
        errors = []
        for i, joint in enumerate(self.tree.joints):
            if not self.lower[i] <= q[i] <= self.upper[i]:
                errors.append(f'{joint} = {q[i]} outside [{self.lower[i]}, {self.upper[i]}]')
            if abs(qd[i]) > self.velocity[i]:
                errors.append(f'{joint} velocity {qd[i]} beyond {self.velocity[i]}')
        gaps = self.clearance(q)
        n_obs = self.obstacles.shape[0]
        for j in np.flatnonzero(gaps < 0.0):
            s, o = divmod(int(j), n_obs)
            errors.append(f'sphere {self.sphere_names[s]} inside obstacle {o} (inflated by the '
                          f'margin) by {-gaps[j]:.6g} m')
        if errors:
            raise SpecError(f'{name} state: ' + '; '.join(errors))

    def inverse_dynamics(self, q, qd, qdd):
        """Torques (N, n) of the CasADi RNEA at rows of q, qd, qdd."""
        rnea = self.model.rnea.map(q.shape[0])
        return np.asarray(rnea(q.T, qd.T, qdd.T)).T

    def path_guess(self, t_f, n_intervals, offsets=None):
        """
        (states, controls, t_f): a cubic from start to goal over t_f, optionally bent.

        The joints follow cubic Hermite curves matching both ends' positions and velocities;
        offsets (n,) adds offsets sin(pi s) (a detour through a shifted midpoint), clipped
        into the position limits.  The controls make the Euler steps of the velocities follow
        the curve (inverse dynamics), clipped to the efforts: the cold start of toc_ros' fast
        mode, for an arm.
        """
        n = self.n
        s = np.linspace(0.0, 1.0, n_intervals + 1)[:, None]
        q0, qg = self.x0[:n], self.xg[:n]
        v0, vg = self.x0[n:] * t_f, self.xg[n:] * t_f
        h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
        h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
        d00, d10 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1
        d01, d11 = -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
        q = h00 * q0 + h10 * v0 + h01 * qg + h11 * vg
        qd = (d00 * q0 + d10 * v0 + d01 * qg + d11 * vg) / t_f
        if offsets is not None:
            q = q + np.sin(np.pi * s) * np.asarray(offsets)[None, :]
            qd = qd + np.pi * np.cos(np.pi * s) * np.asarray(offsets)[None, :] / t_f
            q = np.clip(q, self.lower, self.upper)
        h = t_f / n_intervals
        qdd = (qd[1:] - qd[:-1]) / h
        u = self.inverse_dynamics(q[:-1], qd[:-1], qdd)
        states = np.hstack([q, qd])
        states[0], states[-1] = self.x0, self.xg
        return states, np.clip(u, -self.effort, self.effort), float(t_f)

    def line_time(self, n_intervals=50):
        """
        Return a final time for the cubic line start.

        The shortest on a 5 % grid whose peak velocity and inverse-dynamics torques stay
        within the limits (at most 60 s).
        """
        n = self.n
        dq = np.abs(self.xg[:n] - self.x0[:n])
        t_f = max(1.5 * float(np.max(dq / self.velocity)), 0.05)
        for _ in range(200):
            states, _, _ = self.path_guess(t_f, n_intervals)
            q, qd = states[:, :n], states[:, n:]
            h = t_f / n_intervals
            u = self.inverse_dynamics(q[:-1], qd[:-1], (qd[1:] - qd[:-1]) / h)
            if (np.all(np.abs(u) <= self.effort) and np.all(np.abs(qd) <= self.velocity)) \
                    or t_f > 60.0:
                break
            t_f *= 1.05
        return float(t_f)
