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
User-defined robot models from a model file, derived symbolically with SymPy.

A model file (YAML) names the joints, the parameters with their defaults, the control bounds,
the links as segments in the base x-y plane and EITHER the Lagrangian (kinetic and potential
energy, optional generalised forces) OR the explicit right-hand side dx/dt = f(x, u).  This
module parses it, derives the equations of motion and their exact first and second
derivatives, and generates a Python module with the pointwise kernels of the model interface
(base.py) and the cached horizon / interior-point wrappers, exactly like the hand-written
models: symbolic_parse.py parses, symbolic_derive.py derives, symbolic_print.py prints,
symbolic_codegen.py generates, and this module loads the generated module as a RobotModel
(SymbolicRobot).  The generated module is written into a cache directory keyed by a hash of
the file's content (and of the generator), so the derivation and numba's compilation run once
per model file.

File format (every expression is a SymPy expression string; `^` means power):

    name: my_arm                       # identifier of the model
    description: ...                   # optional free text
    joints:                            # n joints; symbols q1..qn, dq1..dqn, u1..un
      - {name: shoulder_joint, kind: revolute}     # kind: revolute (rad) | prismatic (m)
      - {name: elbow_joint, kind: revolute}
    parameters: {l1: 1.0, m1: 12.0, g: 0.0, u1_max: 250.0, ...}   # defaults
    positive: [l1, m1, u1_max]         # optional: parameters that must be > 0
    u_max: [u1_max, u2_max]            # n expressions of the parameters, each > 0
    definitions:                       # optional, in order: names for sub-expressions of q,
      ex: l1*cos(q1)                   #   dq and parameters (and earlier definitions)
    links:                             # L >= 1 segments [ax, ay, bx, by] of q and parameters
      - [0, 0, ex, ey]
    lagrangian:                        # EITHER: M(q) ddq + ... = Q (Euler-Lagrange)
      kinetic: m1/2*(ddt(ex)^2 + ddt(ey)^2)        # quadratic in dq; ddt(e) = de/dq dq
      potential: m1*g*ey
      forces: [u1, u2 - 0.1*dq2]       # optional generalised forces Q, default u
    dynamics: [dq1, ..., ...]          # OR: the 2 n entries of f in the layout
                                       #   (q1, dq1, q2, dq2, ...) of x, functions of x and u
    inverse_kinematics:                # optional: closed-form hand IK (hand_ik.py); names:
      definitions: {c2: ...}           #   the hand goal x, y, the parameters, min, max
      reach: [x^2 + y^2 <= (l1 + l2)^2]            # conditions (<=, >=, <, >)
      branches:                        # name: one expression per joint
        elbow_up: {q1: ..., q2: ...}

Functions: sin cos tan asin acos atan atan2 sinh cosh tanh exp log sqrt, the constant pi and
ddt (total time derivative of an expression of q).  The file is evaluated by SymPy's parser
(Python's eval with a restricted namespace): load only model files you trust.

Lagrangian models: the accelerations w = M^-1 r are computed in the kernels by an unrolled
LDL^T factorisation of the mass matrix M, their derivatives by implicit differentiation
(symbolic_derive.py).  A pivot at or below SINGULAR_RTOL times the largest diagonal entry of M
raises ModelError from the kernel (never an inf; NaN inputs propagate as NaN); check_state()
reports it for a given state, and a mass matrix singular at every pose tried is refused at load.
Parameter-only sub-expressions are moved out of the kernels into the packed parameter vector
(the parameter values, then the derived constants; see packed()), as the hand-written models
do.  Generated modules live in <NUMBA_CACHE_DIR>/toc_ros-models/<hash>/model_<hash>.py, or
without NUMBA_CACHE_DIR in <XDG_CACHE_HOME or ~/.cache>/toc_ros/models/<hash>/; their numba
machine code is cached with the core's (toc_ros/core/_numba_cache.py).
"""

from dataclasses import dataclass
import math
import os
import sys

import numpy as np

from . import hand_ik
from .base import ModelError, RobotModel
from .generated import cache_root, import_file, write_once
# The names of the parser and the generator are part of this module's interface.
from .symbolic_codegen import content_hash, generate_source  # noqa: F401
from .symbolic_derive import SINGULAR_RTOL
from .symbolic_parse import IKSpec, ModelSpec, parse_model_text  # noqa: F401


def kernel_module(text, source='<string>', cache_dir=None):
    """Return the kernel module of a model file's text (generated on the first use)."""
    model_hash = content_hash(text)
    module_name = f'toc_ros_model_{model_hash}'
    if module_name in sys.modules:
        return sys.modules[module_name]
    path = os.path.join(cache_dir or cache_root(), model_hash, f'model_{model_hash}.py')
    write_once(path, lambda: generate_source(text, source)[0])
    return import_file(path, module_name)


@dataclass(frozen=True)
class SymbolicParams:
    """Parameter values of a generated model (model: the model file's hash)."""

    model: str
    values: tuple            # ((name, value), ...) in the file's order

    def as_dict(self):
        """{name: value}."""
        return dict(self.values)


class SymbolicRobot(RobotModel):
    """A robot model generated from a model file (see the module docstring)."""

    def __init__(self, module, values=None, text=None, source=None):
        values = dict(values or {})
        unknown = sorted(set(values) - set(module.PARAM_NAMES))
        if unknown:
            raise ModelError(f'model {module.NAME!r} has no parameter(s) {", ".join(unknown)} '
                             f'(known: {", ".join(module.PARAM_NAMES) or "none"})')
        merged = []
        for name, default in zip(module.PARAM_NAMES, module.PARAM_DEFAULTS):
            value = values.get(name, default)
            if isinstance(value, str):
                try:
                    value = float(value)
                except ValueError:
                    raise ModelError(f'model {module.NAME!r}: parameter {name} must be a '
                                     f'number, got {value!r}') from None
            merged.append((name, value))
        super().__init__(SymbolicParams(module.MODEL_HASH, tuple(merged)))
        self.kernels = module
        self.name = module.NAME
        self.n_joints = module.N_JOINTS
        self.n_links = module.N_LINKS
        self.joint_kinds = tuple(module.JOINT_KINDS)
        self.default_joint_names = tuple(module.JOINT_NAMES)
        self._text = text
        self._source = source

    def __reduce__(self):
        """Pickle as the file text and the parameter values (regenerated or cache-loaded)."""
        if self._text is None:
            raise TypeError('a SymbolicRobot built without its file text cannot be pickled')
        return (_rebuild, (self._text, self._source, self.params.as_dict()))

    def parameter_values(self):
        """Return {name: value} of the file's parameters."""
        return self.params.as_dict()

    def with_parameters(self, values):
        """Return the same model with some parameter values replaced ({name: value})."""
        return SymbolicRobot(self.kernels, dict(self.params.as_dict(), **values), self._text,
                             self._source)

    def _packed_or_problem(self):
        values = [float(v) for _, v in self.params.values]
        try:
            extra = self.kernels.derived(values)
        except (ArithmeticError, ValueError) as exc:
            return None, f'the parameters give an invalid derived constant ({exc})'
        p = np.array(values + list(extra), dtype=float)
        if not np.all(np.isfinite(p)):
            return None, 'the parameters give a non-finite derived constant'
        return p, None

    def packed(self):
        """Parameter values followed by the derived constants of the kernels."""
        p, problem = self._packed_or_problem()
        if problem:
            raise ModelError(f'model {self.name!r}: {problem}')
        return p

    @property
    def u_max(self):
        """Control bounds from the file's u_max expressions."""
        return self.kernels.control_bounds(self.packed())

    def check(self):
        """Problems with the parameter values."""
        errors = []
        for name, value in self.params.values:
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value)):
                errors.append(f'robot.{name} must be a finite number, got {value!r}')
            elif name in self.kernels.POSITIVE and not value > 0.0:
                errors.append(f'robot.{name} must be a finite positive number, got {value!r}')
        if errors:
            return errors
        p, problem = self._packed_or_problem()
        if problem:
            return [f'model {self.name!r}: {problem}']
        u_max = self.kernels.control_bounds(p)
        for i, bound in enumerate(u_max):
            if not (math.isfinite(bound) and bound > 0.0):
                errors.append(f'u_max[{i}] must be finite and > 0, got {bound!r}')
        return errors

    def mass_matrix(self, q):
        """M(q) (n, n) of a Lagrangian model (ModelError for an explicit-f model)."""
        if self.kernels.mass_matrix is None:
            raise ModelError(f'model {self.name!r} is given by f(x, u): no mass matrix')
        m = np.zeros((self.n_joints, self.n_joints))
        self.kernels.mass_matrix(self.state(q), self.packed(), m)
        return m

    def check_state(self, x, name='state'):
        """Check that a Lagrangian model's mass matrix is positive definite at x."""
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.size != self.nx or not np.all(np.isfinite(x)):
            return [f'{name} must be {self.nx} finite numbers']
        p = self.packed()
        if self.kernels.mass_matrix is not None:
            m = np.zeros((self.n_joints, self.n_joints))
            self.kernels.mass_matrix(x, p, m)
            pivot = _relative_pivot(m)
            if not pivot > SINGULAR_RTOL:
                return [f'{name}: the mass matrix of model {self.name!r} is singular at '
                        f'q = {np.array2string(x[0::2], precision=6)} (smallest relative '
                        f'pivot {pivot:.3g})']
            return []
        f = np.zeros(self.nx)
        try:
            self.kernels.rhs(x, np.zeros(self.nu), p, f)
        except ArithmeticError as exc:
            return [f'{name}: f(x, 0) of model {self.name!r} fails: {exc}']
        if not np.all(np.isfinite(f)):
            return [f'{name}: f(x, 0) of model {self.name!r} is not finite']
        return []

    def link_segments(self, q):
        """(..., L, 4) from the file's link expressions."""
        return self.kernels.link_segments(np.asarray(q, dtype=float), self.packed())

    @property
    def ik_branches(self):
        """Names of the file's closed-form IK branches (empty: numeric IK or none)."""
        return tuple(self.kernels.IK_BRANCHES)

    def inverse_kinematics(self, x, y, branch=None, seed=None):
        """
        Joint positions (n,) that put the hand at (x, y) [m] (hand_ik.py).

        With an inverse_kinematics section: its branch (robot.ik_branch; ignored when there is
        one); without: Newton from seed (joint positions, default zero) for 2 joints.  Raises
        ModelError with the reason for an unreachable, ambiguous or singular goal.
        """
        x, y = float(x), float(y)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ModelError(f'model {self.name!r}: hand goal ({x!r}, {y!r}) is not finite')
        if self.kernels.IK_BRANCHES:
            return hand_ik.closed_form_ik(self, x, y, branch)
        return hand_ik.numeric_ik(self, x, y, seed)


def _relative_pivot(m):
    """Smallest LDL^T pivot of m relative to its largest diagonal entry (<= 0: indefinite)."""
    n = m.shape[0]
    scale = float(np.max(np.abs(np.diag(m))))
    if not scale > 0.0:
        return 0.0
    low = np.zeros_like(m)
    piv = np.zeros(n)
    worst = math.inf
    for j in range(n):
        d = m[j, j] - np.sum(low[j, :j] ** 2 * piv[:j])
        worst = min(worst, d / scale)
        if not d > SINGULAR_RTOL * scale:
            return worst
        piv[j] = d
        for i in range(j + 1, n):
            low[i, j] = (m[i, j] - np.sum(low[i, :j] * low[j, :j] * piv[:j])) / d
    return worst


def _rebuild(text, source, values):
    return model_from_text(text, source, None, **values)


def model_from_text(text, source='<string>', cache_dir=None, **params):
    """Return a SymbolicRobot from a model file's text and parameter overrides."""
    module = kernel_module(text, source, cache_dir)
    model = SymbolicRobot(module, params, text=text, source=source)
    problems = model.check()
    if problems:
        raise ModelError(f'model file {source}: ' + '; '.join(problems))
    _check_not_always_singular(model, source)
    hand_ik.check_branches(model, source)
    return model


def _check_not_always_singular(model, source):
    """Refuse a mass matrix that is singular at q = 0 and at three fixed random poses."""
    if model.kernels.mass_matrix is None:
        return
    rng = np.random.default_rng(20260)
    poses = [np.zeros(model.n_joints)] + [rng.uniform(-2.0, 2.0, model.n_joints)
                                          for _ in range(3)]
    if all(model.check_state(model.state(q)) for q in poses):
        raise ModelError(f'model file {source}: the mass matrix is singular at every pose '
                         f'tried (q = 0 and random poses): check the kinetic energy')


def load_model_file(path, cache_dir=None, **params):
    """Return a SymbolicRobot from the model file at path and parameter overrides."""
    try:
        with open(path, encoding='utf-8') as stream:
            text = stream.read()
    except OSError as exc:
        raise ModelError(f'cannot read model file {path}: {exc.strerror or exc}') from None
    return model_from_text(text, os.path.abspath(path), cache_dir, **params)
