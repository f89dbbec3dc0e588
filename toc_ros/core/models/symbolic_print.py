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
Printing for the model-file kernels: sympy expressions -> straight-line float Python.

The printers (plain float literals, small integer powers as products, sqrt for half powers)
and Block, a kernel's definitions and outputs with their common sub-expressions, emitted
in dependency order; kernel_code adds the reads of the inputs a kernel uses.
symbolic_codegen.py decides which kernels a model gets and what goes in each block.
"""

import re

try:
    import sympy as sp
    from sympy.printing.numpy import NumPyPrinter
    from sympy.printing.precedence import precedence
    from sympy.printing.pycode import PythonCodePrinter
except ImportError:  # pragma: no cover - exercised only where sympy is absent
    sp = None


class PrinterMixin:
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


class MathPrinter(PrinterMixin, PythonCodePrinter if sp else object):
    _sqrt = 'math.sqrt'


class NumpyPrinter(PrinterMixin, NumPyPrinter if sp else object):
    _sqrt = 'numpy.sqrt'


class Block:
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
                              key=sort_key, reverse=True)
                stack.extend((d, False) for d in deps)

        # Definitions with checks are emitted in order; everything else on first use.
        for sym, _, extra, needs in self.defs:
            if extra:
                for s in needs:
                    if s in nodes:
                        emit(s)
                emit(sym)
        for (targets, _), expr in zip(self.outputs, reduced[len(self.defs):]):
            for s in sorted(expr.free_symbols, key=sort_key):
                if s in nodes:
                    emit(s)
            lines.append(f'{" = ".join(targets)} = {printer.doprint(expr)}')
        for s in self.required:
            if s in nodes:
                emit(s)
        return lines


def kernel_code(printer, read, blocks, indent='    '):
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
    reads = [f'{name} = {read(name)}' for name in sorted(used, key=name_key)]
    return [indent + line for line in reads + lines]


def name_key(name):
    head, _, index = name.rpartition('_')
    return (head, int(index)) if index.isdigit() else (name, -1)   # goal_x, goal_y


def sort_key(symbol):
    return name_key(symbol.name)
