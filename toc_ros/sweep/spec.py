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
The sweep spec (YAML): base scenario, axes to vary, limit; parsing, checks and case expansion.

    base: {mode: fast, integrator: euler, N: 300}   # toc-solve long options, without "--"
    grid:                                           # cross product of the listed values
      goal.x: [1.0, 1.5]                            # a list, or {linspace: [start, stop, num]}
      goal.y: {linspace: [1.0, 1.5, 2]}
    zip:                                            # groups of names varied together
      - {obstacles.0.x: [1.0, -1.0], obstacles.0.y: [1.0, 1.2]}
    random: {n: 0, seed: 1, ranges: {goal.q1: [0.5, 1.5]}}   # n samples, uniform in ranges
    limit: 100000                                   # more cases than this: refused
    plot: {x: goal.x, y: goal.y}        # heat-map axes (default: goal.x/y, goal_pose.x/y,
                                        # goal.q1/q2, ...)

Cases are the cross product of the grid axes, each zip group (one axis) and the random
samples (one axis), in that order, the last varying fastest.  Only the structure is checked
here; cases.py turns every case into toc-solve arguments and checks those.
"""

from dataclasses import dataclass, field
import itertools
import math
import os
from typing import Optional, Tuple

import numpy as np
import yaml

TOP_LEVEL = ('base', 'grid', 'zip', 'random', 'limit', 'plot')
DEFAULT_LIMIT = 100000
PLOT_PAIRS = (('goal.x', 'goal.y'), ('goal_pose.x', 'goal_pose.y'), ('goal.q1', 'goal.q2'),
              ('start.x', 'start.y'), ('start.q1', 'start.q2'))


class SpecError(ValueError):
    """The spec cannot be used; the message says where and why."""


@dataclass(frozen=True)
class Axis:
    """One dimension of the cross product: names varied together and their value rows."""

    kind: str                          # 'grid', 'zip' or 'random'
    names: Tuple[str, ...]
    rows: Tuple[tuple, ...]            # rows[i][j]: value of names[j] at step i


@dataclass
class Sweep:
    """A checked spec: base options, axes, limit and plot axes."""

    path: str
    base: dict
    axes: Tuple[Axis, ...]
    limit: int = DEFAULT_LIMIT
    plot: Optional[Tuple[str, str]] = None
    text: str = ''
    column_types: dict = field(default_factory=dict)

    @property
    def names(self):
        """Every varied name, in spec order (one result column each)."""
        return tuple(name for axis in self.axes for name in axis.names)

    @property
    def n_cases(self):
        """Return the number of cases of the cross product (1 when nothing varies)."""
        return math.prod(len(axis.rows) for axis in self.axes)

    def cases(self):
        """Yield one {name: value} dict per case, the last axis varying fastest."""
        names = self.names
        for combo in itertools.product(*(axis.rows for axis in self.axes)):
            yield dict(zip(names, itertools.chain.from_iterable(combo)))

    def plot_axes(self):
        """Return the heat map's (x, y): plot.x/y, else a goal/start pair, else the first two."""
        if self.plot:
            return self.plot
        numeric = [n for n in self.names if self.column_types[n] != 'string']
        for pair in PLOT_PAIRS:
            if set(pair) <= set(numeric):
                return pair
        return tuple(numeric[:2]) if len(numeric) >= 2 else None


def load_spec(path):
    """Read and check a spec file; raise SpecError naming the file and the problem."""
    try:
        with open(path) as stream:
            text = stream.read()
    except OSError as exc:
        raise SpecError(f'cannot read {path}: {exc.strerror or exc}')
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SpecError(f'{path} is not valid YAML: {exc}')
    return parse_spec(doc, path=path, text=text)


def parse_spec(doc, path='<spec>', text=''):
    """Check a spec document (the parsed YAML) and return the Sweep."""
    if not isinstance(doc, dict):
        raise SpecError(f'{path}: the spec must be a mapping with keys {", ".join(TOP_LEVEL)}')
    unknown = [k for k in doc if k not in TOP_LEVEL]
    if unknown:
        raise SpecError(f'{path}: unknown key(s) {", ".join(map(str, unknown))}; '
                        f'allowed: {", ".join(TOP_LEVEL)}')
    base = doc.get('base') or {}
    if not isinstance(base, dict) or not all(isinstance(k, str) for k in base):
        raise SpecError(f'{path}: base must map toc-solve long options (without "--") to '
                        'values')
    base = dict(base)
    if isinstance(base.get('config'), str):
        folder = os.path.dirname(os.path.abspath(path)) if path != '<spec>' else os.getcwd()
        base['config'] = os.path.normpath(os.path.join(folder, os.path.expanduser(
            base['config'])))
    axes = []
    axes += _grid_axes(doc.get('grid'), path)
    axes += _zip_axes(doc.get('zip'), path)
    axes += _random_axis(doc.get('random'), path)
    names = [n for axis in axes for n in axis.names]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise SpecError(f'{path}: {", ".join(repeated)} varied more than once (grid, zip '
                        'and random names must be distinct)')
    limit = doc.get('limit', DEFAULT_LIMIT)
    if not _is_int(limit) or limit < 1:
        raise SpecError(f'{path}: limit must be a positive integer, got {limit!r}')
    sweep = Sweep(path=path, base=base, axes=tuple(axes), limit=int(limit), text=text)
    sweep.column_types = {n: _column_type(axis, j, path) for axis in axes
                          for j, n in enumerate(axis.names)}
    if sweep.n_cases > sweep.limit:
        raise SpecError(f'{path}: the spec expands to {sweep.n_cases} cases, more than its '
                        f'limit {sweep.limit} (raise limit: to run them)')
    sweep.plot = _plot(doc.get('plot'), sweep, path)
    return sweep


def _is_int(value):
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _is_number(value):
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, bool)


def _check_name(name, where, path):
    if not isinstance(name, str) or not name or name.startswith('-') or ' ' in name:
        raise SpecError(f'{path}: {where}: {name!r} is not a name (toc-solve long option '
                        'without "--", or start.*, goal.*, obstacles.K.*; arms: goal_pose.*, '
                        'spheres.K.*)')
    return name


def _values(name, raw, where, path):
    """Return the values of a list of scalars or of {linspace: [start, stop, num]}."""
    if isinstance(raw, dict):
        if set(raw) != {'linspace'}:
            raise SpecError(f'{path}: {where}.{name}: a mapping must be {{linspace: [start, '
                            f'stop, num]}}, got keys {", ".join(map(str, raw))}')
        args = raw['linspace']
        if (not isinstance(args, list) or len(args) != 3 or not all(map(_is_number, args[:2]))
                or not _is_int(args[2]) or args[2] < 1
                or not all(math.isfinite(v) for v in args[:2])):
            raise SpecError(f'{path}: {where}.{name}: linspace takes [start, stop, num] with '
                            f'finite start and stop and an integer num >= 1, got {args!r}')
        return [float(v) for v in np.linspace(float(args[0]), float(args[1]), int(args[2]))]
    if not isinstance(raw, list) or not raw:
        raise SpecError(f'{path}: {where}.{name} must be a non-empty list of values or '
                        f'{{linspace: [start, stop, num]}}, got {raw!r}')
    for value in raw:
        _check_value(name, value, where, path)
    return list(raw)


def _check_value(name, value, where, path):
    if isinstance(value, bool) or not (_is_number(value) or isinstance(value, str)):
        raise SpecError(f'{path}: {where}.{name}: values must be numbers or strings, got '
                        f'{value!r}')
    if _is_number(value) and not math.isfinite(value):
        raise SpecError(f'{path}: {where}.{name}: {value!r} is not a finite number')


def _grid_axes(grid, path):
    if grid is None:
        return []
    if not isinstance(grid, dict):
        raise SpecError(f'{path}: grid must map names to lists of values')
    return [Axis('grid', (_check_name(name, 'grid', path),),
                 tuple((v,) for v in _values(name, raw, 'grid', path)))
            for name, raw in grid.items()]


def _zip_axes(groups, path):
    if groups is None:
        return []
    if isinstance(groups, dict):
        groups = [groups]
    if not isinstance(groups, list):
        raise SpecError(f'{path}: zip must be a list of groups (mappings name -> values of '
                        'equal length)')
    axes = []
    for k, group in enumerate(groups):
        where = f'zip[{k}]'
        if not isinstance(group, dict) or not group:
            raise SpecError(f'{path}: {where} must map names to lists of values')
        columns = {_check_name(n, where, path): _values(n, raw, where, path)
                   for n, raw in group.items()}
        lengths = {n: len(v) for n, v in columns.items()}
        if len(set(lengths.values())) != 1:
            raise SpecError(f'{path}: {where}: the lists of a zip group must have equal '
                            f'lengths, got {lengths}')
        axes.append(Axis('zip', tuple(columns), tuple(zip(*columns.values()))))
    return axes


def _random_axis(spec, path):
    if spec is None:
        return []
    if not isinstance(spec, dict) or set(spec) - {'n', 'seed', 'ranges'}:
        raise SpecError(f'{path}: random must be {{n: N, seed: S, ranges: {{name: [low, '
                        f'high]}}}}, got {spec!r}')
    n, seed, ranges = spec.get('n', 0), spec.get('seed', 0), spec.get('ranges') or {}
    if not _is_int(n) or n < 0:
        raise SpecError(f'{path}: random.n must be an integer >= 0, got {n!r}')
    if not _is_int(seed) or seed < 0:
        raise SpecError(f'{path}: random.seed must be an integer >= 0, got {seed!r}')
    if not isinstance(ranges, dict):
        raise SpecError(f'{path}: random.ranges must map names to [low, high]')
    if n == 0:
        return []
    if not ranges:
        raise SpecError(f'{path}: random.n = {n} but random.ranges is empty')
    bounds = []
    for name, pair in ranges.items():
        _check_name(name, 'random.ranges', path)
        if (not isinstance(pair, list) or len(pair) != 2 or not all(map(_is_number, pair))
                or not all(math.isfinite(v) for v in pair) or not pair[0] < pair[1]):
            raise SpecError(f'{path}: random.ranges.{name} must be [low, high] with finite '
                            f'low < high, got {pair!r}')
        bounds.append((float(pair[0]), float(pair[1])))
    # One generator, one draw per (sample, name) in spec order: the same spec gives the same bits.
    u = np.random.default_rng(int(seed)).random((int(n), len(bounds)))
    low = np.array([b[0] for b in bounds])
    high = np.array([b[1] for b in bounds])
    samples = low + (high - low) * u
    rows = tuple(tuple(float(v) for v in row) for row in samples)
    return [Axis('random', tuple(ranges), rows)]


def _column_type(axis, j, path):
    values = [row[j] for row in axis.rows]
    if all(isinstance(v, str) for v in values):
        return 'string'
    if all(_is_int(v) for v in values):
        return 'int64'
    if all(_is_number(v) for v in values):
        return 'float64'
    raise SpecError(f'{path}: {axis.names[j]} mixes numbers and strings: {values!r}')


def _plot(spec, sweep, path):
    if spec is None:
        return None
    if not isinstance(spec, dict) or set(spec) != {'x', 'y'}:
        raise SpecError(f'{path}: plot must be {{x: NAME, y: NAME}}, got {spec!r}')
    for key in ('x', 'y'):
        name = spec[key]
        if name not in sweep.column_types:
            raise SpecError(f'{path}: plot.{key} = {name!r} is not a varied name '
                            f'({", ".join(sweep.names) or "nothing varies"})')
        if sweep.column_types[name] == 'string':
            raise SpecError(f'{path}: plot.{key} = {name!r} is not numeric')
    if spec['x'] == spec['y']:
        raise SpecError(f'{path}: plot.x and plot.y must differ')
    return (spec['x'], spec['y'])
