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
What a model file's kernels compute (SymPy): the equations of motion and their derivatives.

Lagrangian models: M = d2T/d dq2 (which must not depend on dq or u), the residual
r = Q - (d2L/d dq dq) dq + dL/dq, and the accelerations w = M^-1 r are computed in the kernels
by an unrolled LDL^T factorisation; derivatives by implicit differentiation,
dw/dz = M^-1 (dr/dz - dM/dz w) and, with nu = M^-1 (lam_dq1, ..., lam_dqn),
d2(lam . f)/dz dy = nu . (d2r/dz dy - dM/dz dw/dy - dM/dy dw/dz - d2M/dz dy w).
A pivot of the factorisation at or below SINGULAR_RTOL times the largest diagonal entry of M
raises ModelError from the kernel (never an inf; NaN inputs propagate as NaN).

Parameter-only sub-expressions are moved out of the kernels into the packed parameter vector
(the parameter values, then the derived constants: Hoister), as the hand-written models do.
symbolic_codegen.py prints what these build.
"""

from .base import ModelError

try:
    import sympy as sp
except ImportError:  # pragma: no cover - exercised only where sympy is absent
    sp = None

SINGULAR_RTOL = 1e-12


def euler_lagrange(source, sym, kinetic, potential, forces):
    """M(q) and r(x, u) = Q - (d2L/d dq dq) dq + dL/dq of the Euler-Lagrange equations."""
    n = sym.n
    mass = sp.zeros(n, n)
    for i in range(n):
        for j in range(i, n):
            entry = sp.expand(sp.diff(kinetic, sym.dq[i], sym.dq[j]))
            if entry.has(*sym.dq):
                raise ModelError(f'model file {source}: lagrangian.kinetic: the kinetic energy '
                                 'must be quadratic in the joint velocities (its second '
                                 'derivatives may depend on q only)')
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


class Hoister:
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


class AccelerationTerms:
    """
    The accelerations w = M^-1 r of a Lagrangian ModelSpec and their derivatives, as code.

    Each method adds definitions to a kernel code block (symbolic_print.Block) through its
    define(); expressions pass through hoist (parameter-only parts -> derived constants).
    """

    def __init__(self, spec, sym, hoist, variables):
        self.spec = spec
        self.name = spec.name
        self.n = len(spec.joint_names)
        self.sym = sym
        self.hoist = hoist
        self.vars = variables       # x then u: the variables of the derivatives

    def mass_entry(self, i, j, z=None, y=None):
        """M[i, j], differentiated by z and y when given."""
        entry = self.spec.mass[i, j]
        for v in (z, y):
            if v is not None:
                entry = sp.diff(entry, v)
        return entry

    def factor(self, block):
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
                     f'    raise ModelError("{self.name}: singular mass matrix '
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

    def solve(self, block, factor, rhs, prefix):
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

    def accelerations(self, block):
        """Return (factor of M, symbols of w = M^-1 r)."""
        factor = self.factor(block)
        r = [self.hoist(e) for e in self.spec.residual]
        w = self.solve(block, factor, r, 'w')
        return factor, w

    def acceleration_partials(self, block, factor, w):
        """dw/dz for every z in (x, u): list over z of n symbols."""
        n = self.n
        partials = []
        for z in self.vars:
            v = []
            for i in range(n):
                acc = self.hoist(sp.diff(self.spec.residual[i], z))
                if z in self.sym.q:
                    acc -= sum((self.hoist(self.mass_entry(i, j, z)) * w[j]
                                for j in range(n)), sp.Integer(0))
                v.append(acc)
            if all(e == 0 for e in v):
                partials.append([sp.Integer(0)] * n)
            else:
                partials.append(self.solve(block, factor, v, 'wz'))
        return partials
