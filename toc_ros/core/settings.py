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
Settings: dataclass fields that also describe their flat parameter (name, range, text).

A field declared with ``setting(default, description, ...)`` is the one place of a setting:
its default, description, unit, range and choices.  ``parameter_table(cls, prefix)`` walks a
dataclass (and the dataclass fields nested in it, e.g. ``SolverOptions.paper``) and returns the
flat parameters ('robot.a', 'solver.paper.K_B', ...) that the nodes declare, the scenario YAML
holds and toc-solve lists; ``from_parameters(cls, params, prefix)`` builds the dataclass back
from such a flat dict.  Plain fields (no ``setting``) are not parameters.

Adding an option is one line in its dataclass, e.g. in ``SolverOptions``::

    restarts: int = setting(2, 'number of random restarts', low=0, high=100)

The flat name is ``prefix + (ros_name or field name)``; nested dataclass fields (a
``default_factory`` that is a dataclass) add ``<field name>.`` to the prefix.  Two special
shapes keep the historical parameter names: fields with the same ``ros_name`` and an ``index``
form one array parameter (``robot.u_max`` = [u1_max, u2_max]), and a field of rows with
``columns`` is stored as one array per column (``obstacles.x``, ``obstacles.y``, ...).
``none_value`` maps a parameter value (e.g. 0) to a field value of None ("no limit");
``ros_default`` is the parameter default where it differs from the field's, or where the field
has none (a required field such as a problem's start state).
This module is ROS-free and numba-free.
"""

from dataclasses import dataclass, field, fields, is_dataclass, MISSING
from typing import Optional, Tuple

METADATA_KEY = 'toc_ros.setting'
_NOT_GIVEN = object()


@dataclass(frozen=True)
class Setting:
    """What a field's metadata says about its flat parameter."""

    description: str
    unit: str = ''
    low: Optional[float] = None
    high: Optional[float] = None
    choices: Optional[Tuple[str, ...]] = None
    ros_name: Optional[str] = None
    index: Optional[int] = None              # position in a shared array parameter
    columns: Optional[Tuple[str, ...]] = None   # rows stored as one array per column
    none_value: object = None                # parameter value that means a field value None
    ros_default: object = _NOT_GIVEN         # parameter default when it differs from the field's
    ros_type: Optional[str] = None           # e.g. 'string_array' for an empty default


@dataclass(frozen=True)
class Parameter:
    """One flat parameter: name, default (plain Python), type name, range, description."""

    name: str
    default: object
    ros_type: str        # 'bool', 'integer', 'double', 'string', 'double_array', 'string_array'
    description: str
    unit: str = ''
    low: Optional[float] = None
    high: Optional[float] = None
    choices: Optional[Tuple[str, ...]] = None

    def full_description(self):
        """Return the description with the unit in front, as parameter descriptions show it."""
        return f'[{self.unit}] {self.description}' if self.unit else self.description


def setting(default=MISSING, description='', *, unit='', low=None, high=None, choices=None,
            ros_name=None, index=None, columns=None, none_value=None, ros_default=_NOT_GIVEN,
            ros_type=None, default_factory=MISSING):
    """Return a dataclasses.field with a default and the Setting that describes it."""
    if not description:
        raise ValueError('a setting needs a description')
    meta = Setting(description=description, unit=unit, low=low, high=high,
                   choices=None if choices is None else tuple(choices), ros_name=ros_name,
                   index=index, columns=None if columns is None else tuple(columns),
                   none_value=none_value, ros_default=ros_default, ros_type=ros_type)
    return field(default=default, default_factory=default_factory,
                 metadata={METADATA_KEY: meta})


def _type_name(value):
    if isinstance(value, bool):
        return 'bool'
    if isinstance(value, int):
        return 'integer'
    if isinstance(value, float):
        return 'double'
    if isinstance(value, str):
        return 'string'
    if isinstance(value, (list, tuple)) and value:
        inner = _type_name(value[0])
        if inner in ('double', 'integer', 'string', 'bool'):
            # Mixed int/float arrays are double arrays (parameter types do not convert).
            if inner == 'integer' and any(isinstance(v, float) for v in value):
                inner = 'double'
            return inner + '_array'
    raise TypeError(f'no parameter type for default {value!r}')


def _plain(value):
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def _field_default(f):
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    raise TypeError(f'setting {f.name} has no default')


def _example(f, meta):
    """Return a value of the field's type: its default, else its parameter default."""
    if f.default is MISSING and f.default_factory is MISSING and \
            meta.ros_default is not _NOT_GIVEN:
        return meta.ros_default       # a required field (e.g. a problem's start state)
    return _field_default(f)


def _nested(f):
    """Return the dataclass type of a nested group field, or None."""
    factory = f.default_factory
    if METADATA_KEY not in f.metadata and isinstance(factory, type) and is_dataclass(factory):
        return factory
    return None


def parameter_table(cls, prefix=''):
    """Flat Parameters of a dataclass (nested groups included), in field order."""
    table = []
    shared = {}    # name -> Parameter under construction for index fields
    for f in fields(cls):
        group = _nested(f)
        if group is not None:
            table += parameter_table(group, f'{prefix}{f.name}.')
            continue
        meta = f.metadata.get(METADATA_KEY)
        if meta is None:
            continue
        name = prefix + (meta.ros_name or f.name)
        default = _field_default(f) if meta.ros_default is _NOT_GIVEN else meta.ros_default
        if default is None:
            default = meta.none_value
        common = {'description': meta.description, 'unit': meta.unit, 'low': meta.low,
                  'high': meta.high, 'choices': meta.choices}
        if meta.columns is not None:
            rows = [tuple(row) for row in default]
            for k, column in enumerate(meta.columns):
                values = [_plain(row[k]) for row in rows]
                table.append(Parameter(name=f'{name}.{column}', default=values,
                                       ros_type=_type_name(values or [0.0]), **common))
            continue
        if meta.index is not None:
            entry = shared.get(name)
            if entry is None:
                entry = shared[name] = {'index': len(table), 'values': {}, 'common': common}
                table.append(None)
            entry['values'][meta.index] = _plain(default)
            continue
        default = _plain(default)
        table.append(Parameter(name=name, default=default,
                               ros_type=meta.ros_type or _type_name(default), **common))
    for name, entry in shared.items():
        values = [entry['values'][k] for k in sorted(entry['values'])]
        if sorted(entry['values']) != list(range(len(values))):
            raise TypeError(f'{name}: indices of {cls.__name__} must be 0, 1, ...')
        table[entry['index']] = Parameter(name=name, default=values, ros_type=_type_name(values),
                                          **entry['common'])
    return table


def _convert(value, like):
    """Convert a parameter value to the type of a field's default (TypeError/ValueError)."""
    if isinstance(like, bool):
        if not isinstance(value, bool):
            raise TypeError(f'expected true or false, got {value!r}')
        return value
    if isinstance(like, int):
        try:
            whole = not isinstance(value, bool) and float(value) == int(value)
        except (TypeError, ValueError, OverflowError):
            whole = False
        if not whole:
            raise ValueError(f'expected an integer, got {value!r}')
        return int(value)
    if isinstance(like, float):
        try:
            if isinstance(value, bool):
                raise TypeError
            return float(value)
        except (TypeError, ValueError):
            raise ValueError(f'expected a number, got {value!r}')
    if isinstance(like, str):
        return str(value)
    if isinstance(like, tuple):
        if isinstance(value, (str, bytes)) or not hasattr(value, '__iter__'):
            raise TypeError(f'expected a list, got {value!r}')
        items = list(value)
        inner = like[0] if like else 0.0
        return tuple(_convert(v, inner) for v in items)
    return value


def from_parameters(cls, params, prefix='', **overrides):
    """
    Build cls from flat params (names of parameter_table(cls, prefix)); overrides win.

    Raises KeyError for a missing name, TypeError/ValueError for a value of the wrong kind;
    range and consistency checks are the dataclass's own validate().
    """
    kwargs = {}
    shared = {}
    for f in fields(cls):
        if f.name in overrides:
            kwargs[f.name] = overrides[f.name]
            continue
        group = _nested(f)
        if group is not None:
            kwargs[f.name] = from_parameters(group, params, f'{prefix}{f.name}.')
            continue
        meta = f.metadata.get(METADATA_KEY)
        if meta is None:
            continue
        name = prefix + (meta.ros_name or f.name)
        like = _example(f, meta)
        if meta.columns is not None:
            columns = [list(params[f'{name}.{c}']) for c in meta.columns]
            if len({len(c) for c in columns}) > 1:
                raise ValueError(', '.join(f'{name}.{c}' for c in meta.columns)
                                 + ' must have equal lengths, got '
                                 + ', '.join(str(len(c)) for c in columns))
            row_like = tuple(like[0]) if like else (0.0,) * len(columns)
            try:
                kwargs[f.name] = tuple(tuple(_convert(v, row_like[k])
                                             for k, v in enumerate(row)) for row in zip(*columns))
            except (TypeError, ValueError) as exc:
                raise ValueError(f'{name}: {exc}')
            continue
        if meta.index is not None:
            if name not in shared:
                shared[name] = list(params[name])
                count = sum(1 for g in fields(cls) if g.metadata.get(METADATA_KEY) is not None
                            and (g.metadata[METADATA_KEY].ros_name or g.name) == meta.ros_name)
                if len(shared[name]) != count:
                    raise ValueError(f'{name} must have {count} entries, got '
                                     f'{len(shared[name])}')
            try:
                kwargs[f.name] = _convert(shared[name][meta.index], like)
            except (TypeError, ValueError) as exc:
                raise ValueError(f'{name}: {exc}')
            continue
        value = params[name]
        if meta.none_value is not None and value == meta.none_value:
            kwargs[f.name] = None
            continue
        if like is None:
            like = meta.none_value if meta.ros_default is _NOT_GIVEN else meta.ros_default
        if meta.ros_type == 'string_array':
            like = ('',)
        try:
            kwargs[f.name] = _convert(value, like)
        except (TypeError, ValueError) as exc:
            raise ValueError(f'{name}: {exc}')
    return cls(**kwargs)
