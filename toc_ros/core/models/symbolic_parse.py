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
Parsing of model files (symbolic.py describes the format): YAML text -> ModelSpec.

Every expression is parsed by SymPy with the file's names bound to internal symbols (x_i state,
u_i control, p_i parameters); a Lagrangian section is turned into the mass matrix and the
residual of the Euler-Lagrange equations (symbolic_derive.py).  Errors name the file, the
place in it and the reason (ModelError).
"""

import ast
from dataclasses import dataclass
import keyword
import math
import re

import yaml

from .base import ModelError
from .symbolic_derive import euler_lagrange

try:
    import sympy as sp
    from sympy.core.function import AppliedUndef
    from sympy.parsing.sympy_parser import (auto_number, auto_symbol, convert_xor,
                                            parse_expr)
except ImportError:  # pragma: no cover - exercised only where sympy is absent
    sp = None

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


@dataclass
class ModelSpec:
    """A parsed model file (SymPy expressions in the internal symbols, see Symbols)."""

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


class Symbols:
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
        why = expression_syntax_error(string)
        if why:
            _fail(self.source, where, f'cannot parse {string!r}: {why}')
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


def expression_syntax_error(string):
    """
    Return why string is not an arithmetic expression ('' if it is one).

    SymPy's parser evaluates its input as Python: before it sees a string, the string must be
    numbers, names, + - * / ** ^ and calls of names, and no power may have a numeric exponent
    beyond MAX_EXPONENT (9^9^9^9 would keep SymPy computing an integer for ever).
    """
    try:
        tree = ast.parse(string.replace('^', '**'), mode='eval')
    except SyntaxError as exc:
        return f'not an expression ({exc.msg})'
    return _syntax_error(tree.body)


MAX_EXPONENT = 64.0
_OPERATORS = (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow)


def _syntax_error(node):
    if isinstance(node, ast.Constant):
        ok = isinstance(node.value, (int, float)) and not isinstance(node.value, bool)
        return '' if ok else f'{node.value!r} is not a number'
    if isinstance(node, ast.Name):
        return '' if not node.id.startswith('_') else f'name {node.id!r} is not allowed'
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.UAdd, ast.USub)):
        return _syntax_error(node.operand)
    if isinstance(node, ast.BinOp) and isinstance(node.op, _OPERATORS):
        why = _syntax_error(node.left) or _syntax_error(node.right)
        if not why and isinstance(node.op, ast.Pow):
            exponent = _number(node.right)
            if exponent is not None and not abs(exponent) <= MAX_EXPONENT:
                why = f'a numeric exponent beyond {MAX_EXPONENT:g}'
        return why
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords:
        return _syntax_error(node.func) or next(
            (why for why in map(_syntax_error, node.args) if why), '')
    return f'{type(node).__name__} is not allowed (numbers, names, + - * / ^ and f(...) only)'


def _number(node):
    """Return a numeric constant expression's value (inf: overflow), None if it has names."""
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.UnaryOp):
        value = _number(node.operand)
        return None if value is None else (-value if isinstance(node.op, ast.USub) else value)
    if isinstance(node, ast.BinOp):
        left, right = _number(node.left), _number(node.right)
        if left is None or right is None:
            return None
        try:
            if isinstance(node.op, ast.Pow):
                return math.pow(left, right) if abs(right) <= MAX_EXPONENT else math.inf
            if isinstance(node.op, ast.Div):
                return left / right if right else math.inf
            if isinstance(node.op, ast.Add):
                return left + right
            return left - right if isinstance(node.op, ast.Sub) else left * right
        except (OverflowError, ValueError):
            return math.inf
    return None


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

    sym = Symbols(n, len(param_names))
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
    """M(q) and r(x, u) of the lagrangian section (see symbolic_derive.euler_lagrange)."""
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
    return euler_lagrange(source, sym, kinetic, potential, forces)


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
