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
Code generation of model-file kernels: a ModelSpec -> the source text of a kernel module.

The module holds the pointwise kernels of the model interface (base.py: rhs, rhs_jac,
rhs_hess, segments), numpy/plain-Python helpers (link_segments, hand, the IK branches, the
derived constants and control bounds) and the cached horizon / interior-point wrappers
(generated.WRAPPERS).  Each kernel is straight-line code: the expressions of
symbolic_derive.py with their common sub-expressions, printed as float arithmetic
(symbolic_print.py).  The text is a function of the model file and of these generator modules
only (content_hash), so it can be cached on disk under that hash.
"""

import hashlib
import os

from .generated import WRAPPERS
from .symbolic_derive import AccelerationTerms, Hoister
from .symbolic_parse import parse_model_text, Symbols
from .symbolic_print import Block, kernel_code, MathPrinter, NumpyPrinter

try:
    import sympy as sp
except ImportError:  # pragma: no cover - exercised only where sympy is absent
    sp = None

# The modules whose source decides the generated text (their content is in the cache key).
GENERATOR_FILES = ('symbolic_parse.py', 'symbolic_derive.py', 'symbolic_print.py',
                   'symbolic_codegen.py')


def _generator_digest():
    here = os.path.dirname(os.path.abspath(__file__))
    digest = hashlib.sha256()
    for name in GENERATOR_FILES:
        with open(os.path.join(here, name), 'rb') as stream:
            digest.update(name.encode() + b'\0' + stream.read())
    return digest.hexdigest()


def content_hash(text):
    """Cache key of a model file: its content and the generator's source (16 hex digits)."""
    digest = hashlib.sha256(b'toc_ros symbolic model\0')
    digest.update(_generator_digest().encode() + b'\0' + WRAPPERS.encode() + b'\0')
    digest.update(text.encode('utf-8'))
    return digest.hexdigest()[:16]


class _Generator:
    """Generates the kernel module source of a ModelSpec."""

    def __init__(self, spec, model_hash):
        self.spec = spec
        self.hash = model_hash
        self.n = len(spec.joint_names)
        self.sym = Symbols(self.n, len(spec.param_names))
        self.hoist = Hoister(self.sym.p, len(spec.param_names))
        self.math = MathPrinter({'fully_qualified_modules': True})
        self.numpy = NumpyPrinter({'fully_qualified_modules': True})
        self.vars = self.sym.x + self.sym.u
        self.terms = AccelerationTerms(spec, self.sym, self.hoist, self.vars)

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

    # Kernels ------------------------------------------------------------------------------
    def _f_block(self, write_f=True):
        """
        Return (block, factor, w): the block that evaluates f (factor, w: Lagrangian only).

        The same code evaluates f in rhs, rhs_jac and rhs_hess, so they agree bit for bit.
        """
        block = Block(temps='t')
        if self.spec.kind == 'explicit':
            for i, e in enumerate(self.spec.f):
                block.output(f'f[{i}]', self.hoist(e))
            return block, None, None
        factor, w = self.terms.accelerations(block)
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
        return kernel_code(self.math, self._read, [block])

    def rhs_jac(self):
        """Generate the body of the kernel rhs_jac."""
        first, factor, w = self._f_block()
        block = Block(first, temps='v')
        nx = 2 * self.n
        if self.spec.kind == 'explicit':
            for i, e in enumerate(self.spec.f):
                for c, z in enumerate(self.vars):
                    target = f'fx[{i}, {c}]' if c < nx else f'fu[{i}, {c - nx}]'
                    block.output(target, self.hoist(sp.diff(e, z)))
            return kernel_code(self.math, self._read, [first, block])
        partials = self.terms.acceleration_partials(block, factor, w)
        for j in range(self.n):
            for c in range(len(self.vars)):
                row = f'fx[{2 * j}, {c}]' if c < nx else f'fu[{2 * j}, {c - nx}]'
                block.output(row, 1 if c == 2 * j + 1 else 0)
                row = f'fx[{2 * j + 1}, {c}]' if c < nx else f'fu[{2 * j + 1}, {c - nx}]'
                block.output(row, partials[c][j])
        return kernel_code(self.math, self._read, [first, block])

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
            block = Block(temps='t')
            for a in range(nv):
                for b in range(a, nv):
                    expr = sum((lam[i] * self.hoist(sp.diff(e, self.vars[a], self.vars[b]))
                                for i, e in enumerate(self.spec.f)), sp.Integer(0))
                    block.output(self._hess_target(a, b), expr)
            return kernel_code(self.math, self._read, [block])
        n = self.n
        first, factor, w = self._f_block(write_f=False)
        block = Block(first, temps='v')
        partials = self.terms.acceleration_partials(block, factor, w)
        nu = self.terms.solve(block, factor, [lam[2 * i + 1] for i in range(n)], 'nu')
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
                            acc -= self.hoist(self.terms.mass_entry(i, j, za)) * partials[b][j]
                        if zb in q:
                            acc -= self.hoist(self.terms.mass_entry(i, j, zb)) * partials[a][j]
                        if za in q and zb in q:
                            acc -= self.hoist(self.terms.mass_entry(i, j, za, zb)) * w[j]
                    terms.append(nu[i] * acc)
                block.output(self._hess_target(a, b), sp.Add(*terms))
        return kernel_code(self.math, self._read, [first, block])

    def segments(self):
        """Generate the body of the kernel segments."""
        block = Block()
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
        return kernel_code(self.math, self._read_q, [block])

    def mass_matrix(self):
        """Generate the body of the kernel that writes M(q) (mass matrix)."""
        block = Block()
        for i in range(self.n):
            for j in range(i, self.n):
                targets = (f'm[{i}, {j}]',) if i == j else (f'm[{i}, {j}]', f'm[{j}, {i}]')
                block.output(targets, self.hoist(self.spec.mass[i, j]))
        return kernel_code(self.math, self._read, [block])

    def link_segments(self):
        """Generate the body of the vectorised numpy segments function."""
        block = Block()
        for k, link in enumerate(self.spec.links):
            for r, e in enumerate(link):
                block.output(f'seg[..., {k}, {r}]', self.hoist(e))
        return kernel_code(self.numpy, self._read_numpy, [block])

    def hand(self):
        """Generate the body of the function hand: the last link's end and d hand / dq."""
        block = Block()
        for r, e in enumerate(self.spec.links[-1][2:4]):
            block.output(f'out[{r}]', e)
            for j, q in enumerate(self.sym.q):
                block.output(f'out[{2 + r * self.n + j}]', sp.diff(e, q))
        return kernel_code(self.math, self._read_q, [block])

    def inverse_kinematics(self):
        """Generate the IK functions of the inverse_kinematics section (plain Python)."""
        ik = self.spec.ik
        if ik is None:
            return ['IK_BRANCHES = ()', 'IK_REACH = ()', 'IK_STRICT = ()', 'IK = {}', '', '',
                    'def ik_reach(goal_x, goal_y, p):',
                    '    """No reach conditions: the file has no inverse_kinematics."""',
                    '    return []']
        reach = Block()
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
                 *kernel_code(self.math, self._read, [reach]),
                 f'    return [(out[2 * k], out[2 * k + 1]) for k in range({count})]']
        for k, (name, exprs) in enumerate(ik.branches.items()):
            block = Block()
            for j, e in enumerate(exprs):
                block.output(f'out[{j}]', e)
            lines += ['', '', f'def _ik_{k}(goal_x, goal_y, p):',
                      f'    """Joint positions of IK branch {name!r} (hand at the goal)."""',
                      f'    out = [0.0] * {self.n}',
                      *kernel_code(self.math, self._read, [block]),
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
        u_max = Block()
        for i, e in enumerate(spec.u_max):
            u_max.output(f'out[{i}]', self.hoist(e))
        u_max_lines = kernel_code(self.math, self._read, [u_max])
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
