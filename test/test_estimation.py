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
Online parameter estimation (toc_ros.core.estimation) against plants simulated here.

The plants are integrated with numpy (eq. 37 from test/numpy_model.py; the planar arm's
M(q) q'' + C q' + G = u written out below from issue 13's definition), at 1 kHz with the
control held over 10 ms, and sampled at 100 Hz like plant_node's joint_states (effort = the
applied u), so the estimator sees nothing of the toc_ros kernels' values.
"""

import math

import numpy as np
import numpy_model as nm
import pytest
from toc_ros.core.estimation import parameter_names, ParameterEstimator
from toc_ros.core.models import load_model, ModelError

HEAVY = {'hand_mass': 60.0, 'inertia': 193.0 * 1.2}


def _bang_bang(t, u_max, period=0.8):
    """Return a control that excites both joints: saturated, switching at two rates."""
    return np.array([u_max[0] * math.copysign(1.0, math.sin(2 * math.pi * t / period)),
                     u_max[1] * math.copysign(1.0, math.cos(2 * math.pi * t / (0.7 * period)))])


def _feed(estimator, rhs, x0, u_max, t_end, dt=1e-3, sample_every=10, hold=10):
    x, t = np.array(x0, dtype=float), 0.0
    u = _bang_bang(0.0, u_max)
    for k in range(int(round(t_end / dt))):
        if k % hold == 0:
            u = _bang_bang(t, u_max)
        k1 = rhs(x, u)
        k2 = rhs(x + 0.5 * dt * k1, u)
        k3 = rhs(x + 0.5 * dt * k2, u)
        k4 = rhs(x + dt * k3, u)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        t = (k + 1) * dt
        if (k + 1) % sample_every == 0:
            estimator.add(t, x[0::2], x[1::2], u)
    return x


def _planar_rhs(x, u, m_p=2.0, m2=8.0):
    return nm.planar_2r_f(x, u, m2=m2, mp=m_p, g=9.81)


def test_heavier_cylindrical_plant_is_identified():
    model = load_model('cylindrical')
    estimator = ParameterEstimator(model, ['hand_mass', 'inertia'], window=2.0)
    assert estimator.estimate() is None
    _feed(estimator, lambda x, u: nm.f(x, u, robot=HEAVY), nm.X0, nm.U_MAX, 1.5)
    values = estimator.estimate()
    assert values is not None, estimator.status
    assert values['hand_mass'] == pytest.approx(60.0, rel=5e-3)
    assert values['inertia'] == pytest.approx(231.6, rel=5e-3)
    heavy = estimator.model()
    assert heavy.params.hand_mass == values['hand_mass']
    assert heavy.params.link_mass == model.params.link_mass      # not estimated: unchanged


def test_planar_payload_under_gravity_is_identified():
    model = load_model('planar_2r', g=9.81)
    estimator = ParameterEstimator(model, ['m_p', 'm2'], window=5.0)
    _feed(estimator, lambda x, u: _planar_rhs(x, u, m_p=3.5, m2=7.0), (0.2, 0.0, 0.5, 0.0),
          model.u_max, 1.5)
    values = estimator.estimate()
    assert values is not None, estimator.status
    assert values['m_p'] == pytest.approx(3.5, rel=1e-2)
    assert values['m2'] == pytest.approx(7.0, rel=1e-2)


def test_forgetting_follows_a_payload_change():
    model = load_model('cylindrical')
    estimator = ParameterEstimator(model, ['hand_mass'], window=0.3)
    _feed(estimator, lambda x, u: nm.f(x, u, robot={'hand_mass': 60.0}), nm.X0, nm.U_MAX, 1.0)
    assert estimator.estimate()['hand_mass'] == pytest.approx(60.0, rel=1e-2)
    # The payload is dropped (the plant has the model's hand mass again); a later sample time
    # base continues the same estimator.
    shifted = _Shifted(estimator, 10.0)
    _feed(shifted, lambda x, u: nm.f(x, u), nm.X0, nm.U_MAX, 3.0)
    assert estimator.estimate()['hand_mass'] == pytest.approx(50.0, rel=2e-2)


class _Shifted:
    def __init__(self, estimator, offset):
        self.estimator, self.offset = estimator, offset

    def add(self, t, q, dq, u):
        self.estimator.add(t + self.offset, q, dq, u)


def test_no_estimate_without_excitation_or_with_implausible_efforts():
    model = load_model('cylindrical')
    resting = ParameterEstimator(model, ['hand_mass', 'inertia'], window=2.0)
    for k in range(200):        # at rest, zero effort: every regressor row is zero
        resting.add(0.01 * k, nm.X0[0::2], [0.0, 0.0], [0.0, 0.0])
    assert resting.estimate() is None and 'not excited' in resting.status
    assert resting.model() is None
    # Efforts ten times what the motion needs: a hand mass of ~10x the model's is refused.
    wrong = ParameterEstimator(model, ['hand_mass', 'inertia'], window=2.0)

    def tenfold(x, u):
        return nm.f(x, u / 10.0)
    _feed(wrong, tenfold, nm.X0, nm.U_MAX, 1.0)
    assert wrong.estimate() is None and 'implausible' in wrong.status


def test_gaps_and_switches_are_not_paired():
    model = load_model('cylindrical')
    estimator = ParameterEstimator(model, ['hand_mass'], window=2.0)
    # Samples 0.2 s apart (dropped messages): no pair is formed.
    for k in range(50):
        estimator.add(0.2 * k, [0.1 * k, 1.0], [0.5, 0.1], [600.0, 500.0])
    assert estimator.estimate() is None and estimator.status.startswith('0 of')
    # Consecutive samples whose efforts differ by half the bound (a switch): skipped too.
    estimator.reset()
    for k in range(50):
        estimator.add(0.01 * k, [0.1, 1.0], [0.5, 0.1], [300.0 * (k % 2), 0.0])
    assert estimator.estimate() is None and estimator.status.startswith('0 of')


def test_bad_names_are_refused_with_the_known_ones():
    model = load_model('cylindrical')
    assert {'hand_mass', 'inertia', 'link_mass', 'a'} <= set(parameter_names(model))
    assert 'model_variant' not in parameter_names(model)
    with pytest.raises(ModelError, match='hand_mass'):
        ParameterEstimator(model, ['wheel_radius'], 2.0)
    with pytest.raises(ModelError):
        ParameterEstimator(model, ['model_variant'], 2.0)
    with pytest.raises(ModelError):
        ParameterEstimator(model, ['inertia', 'inertia'], 2.0)
    with pytest.raises(ModelError, match='window'):
        ParameterEstimator(model, ['inertia'], 0.0)


def test_model_file_parameters_can_be_estimated():
    import os
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        'config', 'models', 'planar_2r.yaml')
    model = load_model(path, g=9.81)
    estimator = ParameterEstimator(model, ['m_p'], window=5.0)
    _feed(estimator, lambda x, u: _planar_rhs(x, u, m_p=3.0), (0.2, 0.0, 0.5, 0.0),
          model.u_max, 1.0)
    assert estimator.estimate()['m_p'] == pytest.approx(3.0, rel=1e-2)
    assert estimator.model().parameter_values()['m_p'] == estimator.estimate()['m_p']
