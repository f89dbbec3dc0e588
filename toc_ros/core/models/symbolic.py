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
models.  The module is written into a cache directory keyed by a hash of the file's content
(and of this generator), so the derivation and numba's compilation run once per model file.

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

Lagrangian models: M = d2T/d dq2 (which must not depend on dq or u), the residual
r = Q - (d2L/d dq dq) dq + dL/dq, and the accelerations w = M^-1 r are computed in the kernels
by an unrolled LDL^T factorisation; derivatives by implicit differentiation,
dw/dz = M^-1 (dr/dz - dM/dz w) and, with nu = M^-1 (lam_dq1, ..., lam_dqn),
d2(lam . f)/dz dy = nu . (d2r/dz dy - dM/dz dw/dy - dM/dy dw/dz - d2M/dz dy w).
A pivot of the factorisation at or below SINGULAR_RTOL times the largest diagonal entry of M
raises ModelError from the kernel (never an inf; NaN inputs propagate as NaN); check_state()
reports it for a given state, and a mass matrix singular at every pose tried is refused at load.

Parameter-only sub-expressions are moved out of the kernels into the packed parameter vector
(the parameter values, then the derived constants; see packed()), as the hand-written models
do.  Generated modules live in <NUMBA_CACHE_DIR>/toc_ros-models/<hash>/model_<hash>.py, or
without NUMBA_CACHE_DIR in <XDG_CACHE_HOME or ~/.cache>/toc_ros/models/<hash>/; their numba
machine code is cached with the core's (toc_ros/core/_numba_cache.py).
"""

from dataclasses import dataclass
import hashlib
import keyword
import math
import os
import re
import sys

import numpy as np
import yaml

from . import hand_ik
from .base import ModelError, RobotModel
from .generated import cache_root, import_file, WRAPPERS, write_once

try:
    import sympy as sp
    from sympy.core.function import AppliedUndef
    from sympy.parsing.sympy_parser import (auto_number, auto_symbol, convert_xor,
                                            parse_expr)
    from sympy.printing.numpy import NumPyPrinter
    from sympy.printing.precedence import precedence
    from sympy.printing.pycode import PythonCodePrinter
except ImportError:  # pragma: no cover - exercised only where sympy is absent
    sp = None

SINGULAR_RTOL = 1e-12
JOINT_KINDS = ('revolute', 'prismatic')
TOP_LEVEL_KEYS = ('name', 'description', 'joints', 'parameters', 'positive', 'u_max',
                  'definitions', 'links', 'lagrangian', 'dynamics', 'inverse_kinematics')
IK_KEYS = ('definitions', 'reach', 'branches')
HAND_NAMES = ('x', 'y')       # the hand goal's coordinates in inverse_kinematics
IK_FUNCTIONS = {'min': 'Min', 'max': 'Max'}     # for clamping, inverse_kinematics only
_COMPARISON = re.compile(r'<=|>=|<|>')
FUNCTION_NAMES = ('sin', 'cos', 'tan', 'asin', 'acos', 'atan', 'atan2', 'sinh', 'cosh',
                  'tanh', 'exp', 'log', 'sqrt')
_RESERVED = re.compile(r'^(q|dq|u)[0-9]+$')
_IDENT = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


# ------------------------------------------------------------------------------------------
# Cache location
# ------------------------------------------------------------------------------------------

def _generator_digest():
    with open(os.path.abspath(__file__), 'rb') as stream:
        return hashlib.sha256(stream.read()).hexdigest()


def content_hash(text):
    """Cache key of a model file: its content and the generator's source (16 hex digits)."""
    digest = hashlib.sha256(b'toc_ros symbolic model\0')
    digest.update(_generator_digest().encode() + b'\0' + WRAPPERS.encode() + b'\0')
    digest.update(text.encode('utf-8'))
    return digest.hexdigest()[:16]


# ------------------------------------------------------------------------------------------
# Parsing
# ------------------------------------------------------------------------------------------

@dataclass
class ModelSpec:
    """A parsed model file (SymPy expressions in the internal symbols, see _Symbols)."""

    name: str
    source: str
    joint_names: tuple
    joint_kinds: tuple
    param_names: tuple
    param_defaults: tuple
    positive: tuple
    u_max: list              # n expressions of the parameters
    links: list              # L lists of 4 expressions of q and the parameters
    kind: str                # 'lagrangian' | 'explicit'
    mass: object = None      # n x n sympy Matrix (lagrangian)
    residual: list = None    # n expressions r(x, u) (lagrangian)
    f: list = None           # 2 n expressions (explicit)
    ik: object = None        # IKSpec of the inverse_kinematics section, if any


@dataclass
class IKSpec:
    """The inverse_kinematics section: expressions of the hand goal (x, y) and parameters."""

    goal: tuple              # the internal symbols of x and y
    reach: list              # (text, small side, big side, strict): small <(=) big
    branches: dict           # branch name -> n expressions (q1, ..., qn)


class _Symbols:
    """Internal symbols: x_i state, u_i control, p_i parameters, lam_i multipliers."""

    def __init__(self, n, n_params):
        self.n = n
        self.x = [sp.Symbol(f'x_{i}', real=True) for i in range(2 * n)]
        self.u = [sp.Symbol(f'u_{i}', real=True) for i in range(n)]
        self.p = [sp.Symbol(f'p_{i}', real=True) for i in range(n_params)]
        self.lam = [sp.Symbol(f'lam_{i}', real=True) for i in range(2 * n)]
        self.q = self.x[0::2]
        self.dq = self.x[1::2]


def _fail(source, where, message):
    raise ModelError(f'model file {source}: {where}: {message}')


class _Parser:
    """Expression parser with the file's names bound to the internal symbols."""

    def __init__(self, source, symbols, param_names):
        self.source = source
        self.sym = symbols
        self.user_names = {}
        env = {name: getattr(sp, name) for name in FUNCTION_NAMES}
        env['pi'] = sp.pi
        env['ddt'] = self._ddt
        for j in range(symbols.n):
            env[f'q{j + 1}'] = symbols.q[j]
            env[f'dq{j + 1}'] = symbols.dq[j]
            env[f'u{j + 1}'] = symbols.u[j]
            self.user_names[symbols.q[j]] = f'q{j + 1}'
            self.user_names[symbols.dq[j]] = f'dq{j + 1}'
            self.user_names[symbols.u[j]] = f'u{j + 1}'
        for k, name in enumerate(param_names):
            env[name] = symbols.p[k]
            self.user_names[symbols.p[k]] = name
        self.env = env
        self.globals = {'Symbol': sp.Symbol, 'Function': sp.Function, 'Integer': sp.Integer,
                        'Float': sp.Float, 'Rational': sp.Rational, '__builtins__': {}}

    def _ddt(self, expr):
        expr = sp.sympify(expr)
        if expr.has(*self.sym.dq, *self.sym.u):
            raise ModelError('ddt() takes an expression of q and the parameters only')
        return sum((sp.diff(expr, q) * dq for q, dq in zip(self.sym.q, self.sym.dq)),
                   sp.Integer(0))

    def bind_goal(self):
        """Bind x, y (the hand goal) and min, max for the inverse_kinematics section."""
        goal = tuple(sp.Symbol(f'goal_{name}', real=True) for name in HAND_NAMES)
        for name, symbol in zip(HAND_NAMES, goal):
            self.env[name] = symbol
            self.user_names[symbol] = name
        for name, function in IK_FUNCTIONS.items():
            self.env[name] = getattr(sp, function)
        return goal

    def define(self, name, expr):
        """Bind a definition name to an expression for the following expressions."""
        self.env[name] = expr

    def parse(self, text, where, allowed):
        """Parse one expression; allowed is the set of internal symbols it may contain."""
        if isinstance(text, bool) or not isinstance(text, (str, int, float)):
            _fail(self.source, where, f'expected an expression (string or number), got '
                  f'{text!r}')
        string = str(text).strip()
        if not string:
            _fail(self.source, where, 'empty expression')
        try:
            expr = parse_expr(string, local_dict=dict(self.env), global_dict=self.globals,
                              transformations=(auto_symbol, auto_number, convert_xor))
        except ModelError as exc:
            _fail(self.source, where, f'cannot use {string!r}: {exc}')
        except Exception as exc:  # noqa: B902 - SymPy's parser raises anything eval raises
            _fail(self.source, where, f'cannot parse {string!r}: {type(exc).__name__}: {exc}')
        try:
            expr = sp.sympify(expr)
        except (sp.SympifyError, TypeError) as exc:
            _fail(self.source, where, f'{string!r} is not an expression: {exc}')
        if not isinstance(expr, sp.Expr):
            _fail(self.source, where, f'{string!r} is not a scalar expression')
        undefined = sorted(str(f.func) for f in expr.atoms(AppliedUndef))
        if undefined:
            _fail(self.source, where, f'unknown function(s) {", ".join(undefined)} in '
                  f'{string!r} (known: {", ".join(FUNCTION_NAMES)}, ddt)')
        unknown = sorted(str(s) for s in expr.free_symbols
                         if s not in self.user_names)
        if unknown:
            _fail(self.source, where, f'unknown symbol(s) {", ".join(unknown)} in {string!r}')
        bad = sorted(self.user_names[s] for s in expr.free_symbols if s not in allowed)
        if bad:
            _fail(self.source, where, f'{string!r} may not depend on {", ".join(bad)}')
        if expr.has(sp.zoo, sp.nan, sp.oo, -sp.oo, sp.I):
            _fail(self.source, where, f'{string!r} is not a finite real expression')
        return expr


def _expression_list(source, data, key, size, size_text):
    if not isinstance(data, (list, tuple)) or len(data) != size:
        _fail(source, key, f'expected a list of {size_text}, got {data!r}')
    return list(data)


def parse_model_text(text, source='<string>'):
    """Parse a model file's text into a ModelSpec (ModelError with the reason if invalid)."""
    if sp is None:  # pragma: no cover
        raise ModelError('model files need SymPy: pip install sympy')
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ModelError(f'model file {source}: not valid YAML: {exc}') from None
    if not isinstance(data, dict):
        raise ModelError(f'model file {source}: expected a mapping at the top level, got '
                         f'{type(data).__name__}')
    unknown = sorted(str(k) for k in data if k not in TOP_LEVEL_KEYS)
    if unknown:
        _fail(source, 'top level', f'unknown key(s) {", ".join(unknown)} (known: '
              f'{", ".join(TOP_LEVEL_KEYS)})')
    name = data.get('name')
    if not isinstance(name, str) or not _IDENT.match(name):
        _fail(source, 'name', f'expected an identifier, got {name!r}')

    joints = data.get('joints')
    if not isinstance(joints, list) or not joints:
        _fail(source, 'joints', f'expected a non-empty list of joints, got {joints!r}')
    joint_names, joint_kinds = [], []
    for j, joint in enumerate(joints):
        where = f'joints[{j}]'
        if not isinstance(joint, dict) or set(joint) - {'name', 'kind'}:
            _fail(source, where, f'expected {{name: ..., kind: revolute|prismatic}}, got '
                  f'{joint!r}')
        jname, kind = joint.get('name'), joint.get('kind', 'revolute')
        if not isinstance(jname, str) or not jname:
            _fail(source, where, f'joint name must be a non-empty string, got {jname!r}')
        if kind not in JOINT_KINDS:
            _fail(source, where, f'kind must be one of {JOINT_KINDS}, got {kind!r}')
        joint_names.append(jname)
        joint_kinds.append(kind)
    if len(set(joint_names)) != len(joint_names):
        _fail(source, 'joints', f'joint names must be distinct, got {joint_names}')
    n = len(joints)

    params = data.get('parameters') or {}
    if not isinstance(params, dict):
        _fail(source, 'parameters', f'expected a mapping name: default, got {params!r}')
    param_names, defaults = [], []
    taken = set(FUNCTION_NAMES) | {'pi', 'ddt'}
    for pname, value in params.items():
        where = f'parameters.{pname}'
        if (not isinstance(pname, str) or not _IDENT.match(pname) or keyword.iskeyword(pname)
                or _RESERVED.match(pname) or pname in taken):
            _fail(source, where, 'a parameter name must be an identifier other than q<i>, '
                  'dq<i>, u<i>, a function name, pi or ddt')
        if (isinstance(value, bool) or not isinstance(value, (int, float))
                or not math.isfinite(value)):
            _fail(source, where, f'default must be a finite number, got {value!r}')
        param_names.append(pname)
        defaults.append(float(value))
    positive = data.get('positive') or []
    if not isinstance(positive, list) or any(p not in param_names for p in positive):
        _fail(source, 'positive', f'expected a list of parameter names, got {positive!r}')

    sym = _Symbols(n, len(param_names))
    parser = _Parser(source, sym, param_names)
    p_set, q_set = set(sym.p), set(sym.q) | set(sym.p)
    x_set = set(sym.x) | set(sym.p)
    xu_set = x_set | set(sym.u)

    u_max = [parser.parse(e, f'u_max[{i}]', p_set) for i, e in enumerate(
        _expression_list(source, data.get('u_max'), 'u_max', n,
                         f'{n} control bounds (one per joint)'))]

    definitions = data.get('definitions') or {}
    if not isinstance(definitions, dict):
        _fail(source, 'definitions', f'expected a mapping name: expression, got '
              f'{definitions!r}')
    for dname, text_d in definitions.items():
        where = f'definitions.{dname}'
        if (not isinstance(dname, str) or not _IDENT.match(dname) or keyword.iskeyword(dname)
                or _RESERVED.match(dname) or dname in taken or dname in param_names):
            _fail(source, where, 'a definition name must be an identifier other than the '
                  'parameters, q<i>, dq<i>, u<i>, a function name, pi or ddt')
        parser.define(dname, parser.parse(text_d, where, x_set))

    links = data.get('links')
    if not isinstance(links, list) or not links:
        _fail(source, 'links', f'expected a non-empty list of segments [ax, ay, bx, by], got '
              f'{links!r}')
    link_exprs = []
    for k, link in enumerate(links):
        entries = _expression_list(source, link, f'links[{k}]', 4,
                                   '4 expressions [ax, ay, bx, by]')
        link_exprs.append([parser.parse(e, f'links[{k}][{i}]', q_set)
                           for i, e in enumerate(entries)])

    has_l, has_f = 'lagrangian' in data, 'dynamics' in data
    if has_l == has_f:
        _fail(source, 'top level', 'give exactly one of lagrangian (kinetic and potential '
              'energy) or dynamics (the list of f(x, u))')
    spec = ModelSpec(name=name, source=source, joint_names=tuple(joint_names),
                     joint_kinds=tuple(joint_kinds), param_names=tuple(param_names),
                     param_defaults=tuple(defaults), positive=tuple(positive), u_max=u_max,
                     links=link_exprs, kind='lagrangian' if has_l else 'explicit')
    if has_f:
        entries = _expression_list(source, data['dynamics'], 'dynamics', 2 * n,
                                   f'{2 * n} expressions (dx/dt for x = (q1, dq1, ...))')
        spec.f = [parser.parse(e, f'dynamics[{i}]', xu_set) for i, e in enumerate(entries)]
    else:
        spec.mass, spec.residual = _parse_lagrangian(source, parser, data['lagrangian'])
    if data.get('inverse_kinematics') is not None:
        spec.ik = _parse_ik(source, parser, data['inverse_kinematics'],
                            taken | set(param_names) | set(definitions))
    return spec


def _parse_lagrangian(source, parser, lag):
    """M(q) and r(x, u) of the lagrangian section (see _euler_lagrange)."""
    sym = parser.sym
    n = sym.n
    q_set, x_set = set(sym.q) | set(sym.p), set(sym.x) | set(sym.p)
    xu_set = x_set | set(sym.u)
    if not isinstance(lag, dict) or 'kinetic' not in lag or set(lag) - {
            'kinetic', 'potential', 'forces'}:
        _fail(source, 'lagrangian', f'expected {{kinetic: ..., potential: ..., forces: '
              f'[...]}}, got {lag!r}')
    kinetic = parser.parse(lag['kinetic'], 'lagrangian.kinetic', x_set)
    potential = parser.parse(lag.get('potential', 0), 'lagrangian.potential', q_set)
    if 'forces' in lag:
        forces = [parser.parse(e, f'lagrangian.forces[{i}]', xu_set) for i, e in enumerate(
            _expression_list(source, lag['forces'], 'lagrangian.forces', n,
                             f'{n} generalised forces'))]
    else:
        forces = list(sym.u)
    return _euler_lagrange(source, sym, kinetic, potential, forces)


def _parse_ik(source, parser, section, taken):
    """
    Parse the inverse_kinematics section into an IKSpec (ModelError with the reason).

    taken: the names the section's definitions may not reuse (parameters, model definitions,
    functions); x and y must not be among them.
    """
    where = 'inverse_kinematics'
    if not isinstance(section, dict) or set(section) - set(IK_KEYS) or 'branches' not in section:
        _fail(source, where, f'expected {{definitions: {{...}}, reach: [...], branches: '
              f'{{name: {{q1: ..., ...}}}}}}, got {section!r}')
    clash = sorted(set(HAND_NAMES) & taken)
    if clash:
        _fail(source, where, f'{", ".join(clash)} name the hand goal here: rename the '
              f'parameter or definition {", ".join(clash)}')
    goal = parser.bind_goal()
    allowed = set(goal) | set(parser.sym.p)
    definitions = section.get('definitions') or {}
    if not isinstance(definitions, dict):
        _fail(source, f'{where}.definitions', f'expected a mapping name: expression, got '
              f'{definitions!r}')
    for name, text in definitions.items():
        at = f'{where}.definitions.{name}'
        if (not isinstance(name, str) or not _IDENT.match(name) or keyword.iskeyword(name)
                or _RESERVED.match(name) or name in taken or name in HAND_NAMES
                or name in IK_FUNCTIONS):
            _fail(source, at, 'a definition name must be a new identifier (not x, y, a '
                  'parameter, a model definition, q<i>, dq<i>, u<i>, a function name, pi or ddt)')
        parser.define(name, parser.parse(text, at, allowed))
    reach = section.get('reach') or []
    if not isinstance(reach, list):
        _fail(source, f'{where}.reach', f'expected a list of conditions such as '
              f"'x^2 + y^2 <= (l1 + l2)^2', got {reach!r}")
    conditions = [_parse_condition(parser, text, f'{where}.reach[{k}]', allowed)
                  for k, text in enumerate(reach)]
    branches = section['branches']
    if not isinstance(branches, dict) or not branches:
        _fail(source, f'{where}.branches', f'expected a mapping name: {{q1: ..., ...}} with '
              f'at least one branch, got {branches!r}')
    joints = [f'q{j + 1}' for j in range(parser.sym.n)]
    solutions = {}
    for name, branch in branches.items():
        at = f'{where}.branches.{name}'
        if not isinstance(name, str) or not _IDENT.match(name):
            _fail(source, at, 'a branch name must be an identifier')
        if not isinstance(branch, dict) or sorted(map(str, branch)) != sorted(joints):
            got = sorted(map(str, branch)) if isinstance(branch, dict) else branch
            _fail(source, at, f'expected one expression per joint, {", ".join(joints)}; got '
                  f'{got!r}')
        solutions[name] = [parser.parse(branch[j], f'{at}.{j}', allowed) for j in joints]
    return IKSpec(goal=goal, reach=conditions, branches=solutions)


def _parse_condition(parser, text, where, allowed):
    """(text, small, big, strict) of a reach condition 'a <= b' (or >=, <, >)."""
    if not isinstance(text, str) or len(_COMPARISON.findall(text)) != 1:
        _fail(parser.source, where, f'expected one comparison such as '
              f"'x^2 + y^2 <= (l1 + l2)^2' (<=, >=, < or >), got {text!r}")
    match = _COMPARISON.search(text)
    left = parser.parse(text[:match.start()], where, allowed)
    right = parser.parse(text[match.end():], where, allowed)
    small, big = (left, right) if match.group().startswith('<') else (right, left)
    return text.strip(), small, big, '=' not in match.group()


def _euler_lagrange(source, sym, kinetic, potential, forces):
    """M(q) and r(x, u) = Q - (d2L/d dq dq) dq + dL/dq of the Euler-Lagrange equations."""
    n = sym.n
    mass = sp.zeros(n, n)
    for i in range(n):
        for j in range(i, n):
            entry = sp.expand(sp.diff(kinetic, sym.dq[i], sym.dq[j]))
            if entry.has(*sym.dq):
                _fail(source, 'lagrangian.kinetic', 'the kinetic energy must be quadratic in '
                      'the joint velocities (its second derivatives may depend on q only)')
            mass[i, j] = mass[j, i] = sp.trigsimp(entry)
    # The kinetic energy rebuilt from its simplified parts (the same function of x): the
    # equations of motion then come out in the short form (cos q2 rather than
    # cos q1 cos(q1 + q2) + sin q1 sin(q1 + q2)).
    at_rest = dict.fromkeys(sym.dq, 0)
    linear = [sp.trigsimp(sp.expand(sp.diff(kinetic, dq).subs(at_rest))) for dq in sym.dq]
    kinetic = (sum((mass[i, j] * sym.dq[i] * sym.dq[j] for i in range(n) for j in range(n)),
                   sp.Integer(0)) / 2
               + sum((b * dq for b, dq in zip(linear, sym.dq)), sp.Integer(0))
               + sp.trigsimp(sp.expand(kinetic.subs(at_rest))))
    lagrangian = kinetic - sp.trigsimp(sp.expand(potential))
    residual = []
    for i in range(n):
        momentum = sp.diff(lagrangian, sym.dq[i])
        term = sum((sp.diff(momentum, sym.q[j]) * sym.dq[j] for j in range(n)), sp.Integer(0))
        residual.append(sp.expand(forces[i] - term + sp.diff(lagrangian, sym.q[i])))
    return mass, residual


# ------------------------------------------------------------------------------------------
# Code generation
# ------------------------------------------------------------------------------------------

class _Hoister:
    """Moves parameter-only sub-expressions into derived entries of the packed vector."""

    def __init__(self, params, first_index):
        self.params = set(params)
        self.first = first_index
        self.table = {}
        self.derived = []         # (symbol, expression of the parameters)

    def _const(self, expr):
        if expr.is_Number or expr in self.params:
            return expr
        if -expr in self.table:
            return -self.table[-expr]
        if expr not in self.table:
            symbol = sp.Symbol(f'p_{self.first + len(self.derived)}', real=True)
            self.table[expr] = symbol
            self.derived.append((symbol, expr))
        return self.table[expr]

    def _is_const(self, expr):
        return expr.free_symbols <= self.params

    def __call__(self, expr):
        """Expression with every parameter-only part replaced by a derived symbol."""
        expr = sp.sympify(expr)
        if self._is_const(expr):
            return self._const(expr)
        groups = {}
        for term in sp.Add.make_args(expr):
            coeff, rest = [], []
            for factor in sp.Mul.make_args(term):
                (coeff if self._is_const(factor) else rest).append(factor)
            key = sp.Mul(*[self._inner(f) for f in rest])
            groups[key] = groups.get(key, sp.Integer(0)) + sp.Mul(*coeff)
        return sp.Add(*[self._const(sp.expand(c)) * key for key, c in groups.items()])

    def _inner(self, expr):
        if expr.is_Atom:
            return expr
        if expr.is_Pow:
            base, exp = expr.args
            return sp.Pow(self(base), exp if exp.is_Number else self(exp))
        return expr.func(*[self(a) for a in expr.args])


class _PrinterMixin:
    """Plain float literals, small integer powers as products, sqrt for x^(1/2)."""

    def _print_Integer(self, expr):
        return repr(float(expr))

    def _print_Rational(self, expr):
        return repr(float(expr))

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Half(self, expr):
        return '0.5'

    def _print_Pow(self, expr, rational=False):
        base, exp = expr.as_base_exp()
        b = self.parenthesize(base, precedence(expr), strict=True)
        if exp.is_Integer and 1 <= abs(int(exp)) <= 4:
            product = '*'.join([b] * abs(int(exp)))
            return f'({product})' if exp > 0 else f'(1.0/({product}))'
        if exp == sp.Rational(1, 2):
            return f'{self._module_format(self._sqrt)}({self._print(base)})'
        if exp == sp.Rational(-1, 2):
            return f'(1.0/{self._module_format(self._sqrt)}({self._print(base)}))'
        if exp.is_Integer:
            return f'({b}**{int(exp)})'
        return f'({b}**{self.parenthesize(exp, precedence(expr), strict=True)})'


class _MathPrinter(_PrinterMixin, PythonCodePrinter if sp else object):
    _sqrt = 'math.sqrt'


class _NumpyPrinter(_PrinterMixin, NumPyPrinter if sp else object):
    _sqrt = 'numpy.sqrt'


class _Block:
    """Straight-line code: definitions (symbol = expression [+ check lines]) and outputs."""

    def __init__(self, after=None, temps='t'):
        self.defs = []            # (symbol, expr, extra lines, symbols they need)
        self.outputs = []         # (targets, expr)
        self.required = []        # symbols later blocks use
        self.count = after.count if after is not None else 0
        self.temps = temps

    def define(self, prefix, expr, extra=()):
        """Return a new symbol for expr (expr itself when it is a number or a symbol)."""
        expr = sp.sympify(expr)
        if expr.is_Atom and not extra:
            return expr
        symbol = sp.Symbol(f'{prefix}_{self.count}', real=True)
        self.count += 1
        self.defs.append((symbol, expr, tuple(extra), ()))
        return symbol

    def require(self, symbols):
        """Emit the definitions of symbols even if no output of this block needs them."""
        self.required.extend(s for s in symbols if isinstance(s, sp.Symbol))

    def output(self, targets, expr):
        """Write expr to the target(s), e.g. 'f[1]' or ('hxx[0, 1]', 'hxx[1, 0]')."""
        if isinstance(targets, str):
            targets = (targets,)
        self.outputs.append((tuple(targets), sp.sympify(expr)))

    def code(self, printer):
        """Source lines: common sub-expressions and definitions, outputs."""
        exprs = [d[1] for d in self.defs] + [e for _, e in self.outputs]
        temps, reduced = sp.cse(exprs, symbols=sp.numbered_symbols(f'{self.temps}_',
                                                                   real=True), order='none')
        nodes = {}
        for sym, expr in temps:
            nodes[sym] = (expr, ())
        for (sym, _, extra, _), expr in zip(self.defs, reduced):
            nodes[sym] = (expr, extra)
        lines, done = [], set()

        def emit(sym):
            # Depth-first: every statement right after the statements it needs.
            stack = [(sym, False)]
            while stack:
                node, ready = stack.pop()
                if node in done:
                    continue
                expr, extra = nodes[node]
                if ready:
                    done.add(node)
                    lines.append(f'{node} = {printer.doprint(expr)}')
                    lines.extend(extra)
                    continue
                stack.append((node, True))
                deps = sorted((s for s in expr.free_symbols if s in nodes and s not in done),
                              key=_sort_key, reverse=True)
                stack.extend((d, False) for d in deps)

        # Definitions with checks are emitted in order; everything else on first use.
        for sym, _, extra, needs in self.defs:
            if extra:
                for s in needs:
                    if s in nodes:
                        emit(s)
                emit(sym)
        for (targets, _), expr in zip(self.outputs, reduced[len(self.defs):]):
            for s in sorted(expr.free_symbols, key=_sort_key):
                if s in nodes:
                    emit(s)
            lines.append(f'{" = ".join(targets)} = {printer.doprint(expr)}')
        for s in self.required:
            if s in nodes:
                emit(s)
        return lines


def _kernel_code(printer, read, blocks, indent='    '):
    """
    Input reads and the code of the blocks in order (each its own common sub-expressions).

    read(name) gives the source of an input symbol's value (e.g. 'x[2]' for x_2).
    """
    lines = []
    for block in blocks:
        lines.extend(block.code(printer))
    used = set()
    for line in lines:
        used.update(re.findall(r'\b(?:x|u|p|lam)_[0-9]+\b', line))
    reads = [f'{name} = {read(name)}' for name in sorted(used, key=_name_key)]
    return [indent + line for line in reads + lines]


def _name_key(name):
    head, _, index = name.rpartition('_')
    return (head, int(index)) if index.isdigit() else (name, -1)   # goal_x, goal_y


def _sort_key(symbol):
    return _name_key(symbol.name)


class _Generator:
    """Generates the kernel module source of a ModelSpec."""

    def __init__(self, spec, model_hash):
        self.spec = spec
        self.hash = model_hash
        self.n = len(spec.joint_names)
        self.sym = _Symbols(self.n, len(spec.param_names))
        self.hoist = _Hoister(self.sym.p, len(spec.param_names))
        self.math = _MathPrinter({'fully_qualified_modules': True})
        self.numpy = _NumpyPrinter({'fully_qualified_modules': True})
        self.vars = self.sym.x + self.sym.u

    # Inputs of the kernels ----------------------------------------------------------------
    @staticmethod
    def _read(name):
        """Kernel argument entry of an input symbol: x_2 -> x[2], lam_1 -> lam[1]."""
        head, _, index = name.rpartition('_')
        return f'{head}[{index}]'

    @staticmethod
    def _read_q(name):
        """As _read, with the state entries x_(2j) read from q[j] (segments kernel)."""
        head, _, index = name.rpartition('_')
        if head == 'x':
            return f'q[{int(index) // 2}]'
        return f'{head}[{index}]'

    @staticmethod
    def _read_numpy(name):
        """As _read_q for the numpy link_segments: q[..., j]."""
        head, _, index = name.rpartition('_')
        if head == 'x':
            return f'q[..., {int(index) // 2}]'
        return f'{head}[{index}]'

    # Lagrangian pieces --------------------------------------------------------------------
    def _mass_entry(self, i, j, z=None, y=None):
        entry = self.spec.mass[i, j]
        for v in (z, y):
            if v is not None:
                entry = sp.diff(entry, v)
        return entry

    def _factor(self, block):
        """Unrolled LDL^T of M: returns (L (dict), inverse pivots)."""
        n = self.n
        m = {}
        for i in range(n):
            for j in range(i + 1):
                m[i, j] = block.define('m', self.hoist(self.spec.mass[i, j]))
        low, piv, inv = {}, [], []
        scale = block.define('mscale', sp.Max(*[sp.Abs(m[j, j]) for j in range(n)]))
        for j in range(n):
            d = m[j, j] - sum((low[j, k] ** 2 * piv[k] for k in range(j)), sp.Integer(0))
            d_sym = sp.Symbol(f'd_{block.count}', real=True)
            check = (f'if {d_sym} <= {SINGULAR_RTOL!r} * {scale}:',
                     f'    raise ModelError("{self.spec.name}: singular mass matrix '
                     f'(pivot {j} <= {SINGULAR_RTOL:g} of the largest diagonal entry)")')
            block.count += 1
            block.defs.append((d_sym, sp.sympify(d), check, (scale,)))
            piv.append(d_sym)
            inv.append(block.define('dinv', 1 / d_sym))
            for i in range(j + 1, n):
                acc = m[i, j] - sum((low[i, k] * low[j, k] * piv[k] for k in range(j)),
                                    sp.Integer(0))
                low[i, j] = block.define('ell', acc * inv[j])
        return low, inv

    def _solve(self, block, factor, rhs, prefix):
        """Symbols of M^-1 rhs by the unrolled factorisation."""
        low, inv = factor
        n = self.n
        y = []
        for i in range(n):
            y.append(block.define(prefix + 'y', rhs[i] - sum(
                (low[i, k] * y[k] for k in range(i)), sp.Integer(0))))
        w = [None] * n
        for i in reversed(range(n)):
            w[i] = block.define(prefix, y[i] * inv[i] - sum(
                (low[k, i] * w[k] for k in range(i + 1, n)), sp.Integer(0)))
        return w

    def _accelerations(self, block):
        factor = self._factor(block)
        r = [self.hoist(e) for e in self.spec.residual]
        w = self._solve(block, factor, r, 'w')
        return factor, w

    def _acceleration_partials(self, block, factor, w):
        """dw/dz for every z in (x, u): list over z of n symbols."""
        n = self.n
        partials = []
        for z in self.vars:
            v = []
            for i in range(n):
                acc = self.hoist(sp.diff(self.spec.residual[i], z))
                if z in self.sym.q:
                    acc -= sum((self.hoist(self._mass_entry(i, j, z)) * w[j]
                                for j in range(n)), sp.Integer(0))
                v.append(acc)
            if all(e == 0 for e in v):
                partials.append([sp.Integer(0)] * n)
            else:
                partials.append(self._solve(block, factor, v, 'wz'))
        return partials

    # Kernels ------------------------------------------------------------------------------
    def _f_block(self, write_f=True):
        """
        Return (block, factor, w): the block that evaluates f (factor, w: Lagrangian only).

        The same code evaluates f in rhs, rhs_jac and rhs_hess, so they agree bit for bit.
        """
        block = _Block(temps='t')
        if self.spec.kind == 'explicit':
            for i, e in enumerate(self.spec.f):
                block.output(f'f[{i}]', self.hoist(e))
            return block, None, None
        factor, w = self._accelerations(block)
        low, inv = factor
        block.require(list(w) + list(low.values()) + list(inv))
        if write_f:
            for j in range(self.n):
                block.output(f'f[{2 * j}]', self.sym.dq[j])
                block.output(f'f[{2 * j + 1}]', w[j])
        return block, factor, w

    def rhs(self):
        """Generate the body of the kernel rhs."""
        block, _, _ = self._f_block()
        return _kernel_code(self.math, self._read, [block])

    def rhs_jac(self):
        """Generate the body of the kernel rhs_jac."""
        first, factor, w = self._f_block()
        block = _Block(first, temps='v')
        nx = 2 * self.n
        if self.spec.kind == 'explicit':
            for i, e in enumerate(self.spec.f):
                for c, z in enumerate(self.vars):
                    target = f'fx[{i}, {c}]' if c < nx else f'fu[{i}, {c - nx}]'
                    block.output(target, self.hoist(sp.diff(e, z)))
            return _kernel_code(self.math, self._read, [first, block])
        partials = self._acceleration_partials(block, factor, w)
        for j in range(self.n):
            for c in range(len(self.vars)):
                row = f'fx[{2 * j}, {c}]' if c < nx else f'fu[{2 * j}, {c - nx}]'
                block.output(row, 1 if c == 2 * j + 1 else 0)
                row = f'fx[{2 * j + 1}, {c}]' if c < nx else f'fu[{2 * j + 1}, {c - nx}]'
                block.output(row, partials[c][j])
        return _kernel_code(self.math, self._read, [first, block])

    def _hess_target(self, a, b):
        nx = 2 * self.n
        if a < nx and b < nx:
            return (f'hxx[{a}, {b}]',) if a == b else (f'hxx[{a}, {b}]', f'hxx[{b}, {a}]')
        if a < nx:
            return (f'hxu[{a}, {b - nx}]',)
        a, b = a - nx, b - nx
        return (f'huu[{a}, {b}]',) if a == b else (f'huu[{a}, {b}]', f'huu[{b}, {a}]')

    def rhs_hess(self):
        """Generate the body of the kernel rhs_hess."""
        nv = len(self.vars)
        lam = self.sym.lam
        if self.spec.kind == 'explicit':
            block = _Block(temps='t')
            for a in range(nv):
                for b in range(a, nv):
                    expr = sum((lam[i] * self.hoist(sp.diff(e, self.vars[a], self.vars[b]))
                                for i, e in enumerate(self.spec.f)), sp.Integer(0))
                    block.output(self._hess_target(a, b), expr)
            return _kernel_code(self.math, self._read, [block])
        n = self.n
        first, factor, w = self._f_block(write_f=False)
        block = _Block(first, temps='v')
        partials = self._acceleration_partials(block, factor, w)
        nu = self._solve(block, factor, [lam[2 * i + 1] for i in range(n)], 'nu')
        q = set(self.sym.q)
        for a in range(nv):
            za = self.vars[a]
            for b in range(a, nv):
                zb = self.vars[b]
                terms = []
                for i in range(n):
                    acc = self.hoist(sp.diff(self.spec.residual[i], za, zb))
                    for j in range(n):
                        if za in q:
                            acc -= self.hoist(self._mass_entry(i, j, za)) * partials[b][j]
                        if zb in q:
                            acc -= self.hoist(self._mass_entry(i, j, zb)) * partials[a][j]
                        if za in q and zb in q:
                            acc -= self.hoist(self._mass_entry(i, j, za, zb)) * w[j]
                    terms.append(nu[i] * acc)
                block.output(self._hess_target(a, b), sp.Add(*terms))
        return _kernel_code(self.math, self._read, [first, block])

    def segments(self):
        """Generate the body of the kernel segments."""
        block = _Block()
        q = self.sym.q
        for k, link in enumerate(self.spec.links):
            for r, e in enumerate(link):
                block.output(f'seg[{k}, {r}]', self.hoist(e))
                for j in range(self.n):
                    d = sp.diff(e, q[j])
                    block.output(f'seg_q[{k}, {r}, {j}]', self.hoist(d))
                    for i in range(j, self.n):
                        targets = (f'seg_qq[{k}, {r}, {j}, {i}]',) if i == j else (
                            f'seg_qq[{k}, {r}, {j}, {i}]', f'seg_qq[{k}, {r}, {i}, {j}]')
                        block.output(targets, self.hoist(sp.diff(d, q[i])))
        return _kernel_code(self.math, self._read_q, [block])

    def mass_matrix(self):
        """Generate the body of the kernel that writes M(q) (mass matrix)."""
        block = _Block()
        for i in range(self.n):
            for j in range(i, self.n):
                targets = (f'm[{i}, {j}]',) if i == j else (f'm[{i}, {j}]', f'm[{j}, {i}]')
                block.output(targets, self.hoist(self.spec.mass[i, j]))
        return _kernel_code(self.math, self._read, [block])

    def link_segments(self):
        """Generate the body of the vectorised numpy segments function."""
        block = _Block()
        for k, link in enumerate(self.spec.links):
            for r, e in enumerate(link):
                block.output(f'seg[..., {k}, {r}]', self.hoist(e))
        return _kernel_code(self.numpy, self._read_numpy, [block])

    def hand(self):
        """Generate the body of the function hand: the last link's end and d hand / dq."""
        block = _Block()
        for r, e in enumerate(self.spec.links[-1][2:4]):
            block.output(f'out[{r}]', e)
            for j, q in enumerate(self.sym.q):
                block.output(f'out[{2 + r * self.n + j}]', sp.diff(e, q))
        return _kernel_code(self.math, self._read_q, [block])

    def inverse_kinematics(self):
        """Generate the IK functions of the inverse_kinematics section (plain Python)."""
        ik = self.spec.ik
        if ik is None:
            return ['IK_BRANCHES = ()', 'IK_REACH = ()', 'IK_STRICT = ()', 'IK = {}', '', '',
                    'def ik_reach(goal_x, goal_y, p):',
                    '    """No reach conditions: the file has no inverse_kinematics."""',
                    '    return []']
        reach = _Block()
        for k, (_, small, big, _) in enumerate(ik.reach):
            reach.output(f'out[{2 * k}]', small)
            reach.output(f'out[{2 * k + 1}]', big)
        count = len(ik.reach)
        lines = [f'IK_BRANCHES = {tuple(ik.branches)!r}',
                 f'IK_REACH = {tuple(c[0] for c in ik.reach)!r}',
                 f'IK_STRICT = {tuple(c[3] for c in ik.reach)!r}', '', '',
                 'def ik_reach(goal_x, goal_y, p):',
                 '    """Sides (small, big) of the reach conditions small <= big."""',
                 f'    out = [0.0] * {2 * count}',
                 *_kernel_code(self.math, self._read, [reach]),
                 f'    return [(out[2 * k], out[2 * k + 1]) for k in range({count})]']
        for k, (name, exprs) in enumerate(ik.branches.items()):
            block = _Block()
            for j, e in enumerate(exprs):
                block.output(f'out[{j}]', e)
            lines += ['', '', f'def _ik_{k}(goal_x, goal_y, p):',
                      f'    """Joint positions of IK branch {name!r} (hand at the goal)."""',
                      f'    out = [0.0] * {self.n}',
                      *_kernel_code(self.math, self._read, [block]),
                      '    return out']
        entries = ', '.join(f'{name!r}: _ik_{k}' for k, name in enumerate(ik.branches))
        return lines + ['', '', f'IK = {{{entries}}}']

    # Module -------------------------------------------------------------------------------
    def source(self):
        """Return the generated module's source text."""
        spec = self.spec
        kernels = [('rhs', '(x, u, p, f)', 'dx/dt = f(x, u) into f.', self.rhs()),
                   ('rhs_jac', '(x, u, p, f, fx, fu)', 'f, df/dx, df/du.', self.rhs_jac()),
                   ('rhs_hess', '(x, u, p, lam, hxx, hxu, huu)',
                    'Second derivatives of lam . f(x, u).', self.rhs_hess()),
                   ('segments', '(q, p, seg, seg_q, seg_qq)',
                    'Link segments and their first and second derivatives wrt q.',
                    self.segments())]
        mass = self.mass_matrix() if spec.kind == 'lagrangian' else None
        link_np = self.link_segments()
        u_max = _Block()
        for i, e in enumerate(spec.u_max):
            u_max.output(f'out[{i}]', self.hoist(e))
        u_max_lines = _kernel_code(self.math, self._read, [u_max])
        n_params = len(spec.param_names)
        derived = [f'    p_{i} = p[{i}]' for i in range(n_params)]
        derived.append(f'    out = [0.0] * {len(self.hoist.derived)}')
        for k, (_, expr) in enumerate(self.hoist.derived):
            derived.append(f'    out[{k}] = {self.math.doprint(expr)}')
        lines = [
            f'"""Kernels of the robot model {spec.name!r} generated by '
            f'toc_ros.core.models.symbolic (do not edit)."""',
            '',
            '# A function of the content of the model file only (cache key MODEL_HASH).',
            '# flake8: noqa',
            '',
            'import math',
            'import sys',
            '',
            'from numba import njit',
            'import numpy',
            '',
            'from toc_ros.core import horizon, ipm',
            'from toc_ros.core.models.base import ModelError',
            '',
            f'MODEL_HASH = {self.hash!r}',
            f'NAME = {spec.name!r}',
            f'KIND = {spec.kind!r}',
            f'JOINT_NAMES = {spec.joint_names!r}',
            f'JOINT_KINDS = {spec.joint_kinds!r}',
            f'PARAM_NAMES = {spec.param_names!r}',
            f'PARAM_DEFAULTS = {spec.param_defaults!r}',
            f'POSITIVE = {spec.positive!r}',
            f'N_JOINTS = {self.n}',
            f'N_LINKS = {len(spec.links)}',
            f'N_DERIVED = {len(self.hoist.derived)}',
            '',
            '',
            'def derived(p):',
            '    """Parameter-only constants of the kernels from the parameter values p."""',
            *derived,
            '    return out',
            '',
            '',
            'def control_bounds(p):',
            '    """u_max from the packed parameters."""',
            f'    out = numpy.empty({self.n})',
            *u_max_lines,
            '    return out',
            '',
            '',
            'def link_segments(q, p):',
            '    """Segments (..., L, 4) for joint positions q (..., n) (numpy)."""',
            '    q = numpy.asarray(q, dtype=float)',
            f'    seg = numpy.zeros(q.shape[:-1] + ({len(spec.links)}, 4))',
            *link_np,
            '    return seg',
            '',
            '',
            'def hand(q, p):',
            '    """Hand [hx, hy, d hx / dq (n), d hy / dq (n)] at q (plain Python)."""',
            f'    out = [0.0] * {2 + 2 * self.n}',
            *self.hand(),
            '    return out',
            '',
            '',
            *self.inverse_kinematics(),
        ]
        for name, args, doc, body in kernels:
            lines += ['', '', "@njit(cache=True, inline='always')", f'def {name}{args}:',
                      f'    """{doc}"""', *body]
        if mass is not None:
            lines += ['', '', '@njit(cache=True)', 'def mass_matrix(x, p, m):',
                      '    """M(q) into m (n x n)."""', *mass]
        else:
            lines += ['', '', 'mass_matrix = None']
        lines += ['', '', 'this = sys.modules[__name__]', '', '', WRAPPERS]
        return '\n'.join(lines) + '\n'


def generate_source(text, source='<string>'):
    """Return (module source, hash) of a model file's text (ModelError if invalid)."""
    spec = parse_model_text(text, source)
    model_hash = content_hash(text)
    return _Generator(spec, model_hash).source(), model_hash


# ------------------------------------------------------------------------------------------
# Loading
# ------------------------------------------------------------------------------------------

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
