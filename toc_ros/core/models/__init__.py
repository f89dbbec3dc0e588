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
Robot models behind one interface (base.py).

The paper's cylindrical robot, planar_2r, model files (symbolic.py), each optionally with
first-order actuators (actuated.py).
"""

import dataclasses
import os
from typing import Tuple

from .actuated import ActuatedModel, with_actuator_lag
from .base import ModelError, RobotModel
from .cylindrical import CylindricalRobot
from .planar_2r import Planar2R, Planar2RParams
from ..settings import setting

MODELS = {'cylindrical': CylindricalRobot, 'planar_2r': Planar2R}
MODEL_FILE_SUFFIXES = ('.yaml', '.yml')


@dataclasses.dataclass(frozen=True)
class ModelChoice:
    """The robot model of a scenario: the parameters robot.model and robot.model_parameters."""

    name: str = setting(
        'cylindrical', "robot model: 'cylindrical' (eq. 37 with the robot.* data), "
        "'planar_2r', or a model file (.yaml; a bare file name is also looked up in the "
        "package's config/models)", ros_name='model')
    parameters: Tuple[str, ...] = setting(
        (), "model parameters as 'name=value' (e.g. l1=0.9, g=9.81); empty: the model's "
        "defaults (for 'cylindrical': the robot.* values, which these override)",
        ros_name='model_parameters', ros_type='string_array')
    actuator_lag: float = setting(
        0.0, "time constant T of the drives' torque (force) response, a first-order lag per "
        'joint that the plans model (models/actuated.py: the applied effort is a state, the '
        'trajectory commands what the drives are asked for); 0 = ideal actuators',
        unit='s', low=0.0, high=1.0)

    def parameter_values(self):
        """{name: value text} of the parameters (ModelError for an entry without '=')."""
        values = {}
        for entry in self.parameters:
            key, sep, value = str(entry).partition('=')
            key, value = key.strip(), value.strip()
            if not sep or not key or not value:
                raise ModelError(f"robot.model_parameters entries must be 'name=value', got "
                                 f'{entry!r}')
            if key in values:
                raise ModelError(f'robot.model_parameters gives {key} twice')
            values[key] = value
        return values


def _builtin(name, params):
    cls = MODELS[name]
    defaults = cls().params
    fields = {f.name: f for f in dataclasses.fields(defaults)}
    unknown = sorted(set(params) - set(fields))
    if unknown:
        raise ModelError(f'model {name!r} has no parameter(s) {", ".join(unknown)} '
                         f'(known: {", ".join(fields)})')
    values = {}
    for key, value in params.items():
        default = getattr(defaults, key)
        if isinstance(value, str) and isinstance(default, float):
            try:
                value = float(value)
            except ValueError:
                raise ModelError(f'model {name!r}: parameter {key} must be a number, got '
                                 f'{value!r}') from None
        values[key] = value
    model = cls(dataclasses.replace(defaults, **values))
    problems = model.check()
    if problems:
        raise ModelError(f'model {name!r}: ' + '; '.join(problems))
    return model


def load_model(name_or_path, **params):
    """
    Return a robot model by built-in name (MODELS) or from a model file (symbolic.py).

    params override the model's parameters (numbers, or strings that parse as numbers);
    raises ModelError for an unknown name, a missing or invalid file or invalid parameters.
    """
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ModelError(f'model must be a name or a file path, got {name_or_path!r}')
    key = os.fspath(name_or_path)
    if key in MODELS:
        return _builtin(key, params)
    if key.lower().endswith(MODEL_FILE_SUFFIXES) or os.sep in key or os.path.exists(key):
        from .symbolic import load_model_file   # SymPy is needed for model files only
        return load_model_file(key, **params)
    raise ModelError(f'unknown model {key!r}: the built-in models are '
                     f'{", ".join(sorted(MODELS))}, or give the path of a model file (.yaml)')


__all__ = ['ActuatedModel', 'CylindricalRobot', 'load_model', 'ModelChoice', 'ModelError',
           'MODELS', 'Planar2R',
           'Planar2RParams', 'RobotModel', 'with_actuator_lag']
