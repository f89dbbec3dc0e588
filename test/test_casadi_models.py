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

"""The CasADi model expressions (benchmarks/casadi_models.py) against the numba kernels."""

from pathlib import Path

from benchmarks import casadi_models as cm
import numpy as np
import pytest

from toc_ros.core.models import load_model

pytest.importorskip('casadi')

ROOT = Path(__file__).resolve().parents[1]

PLANAR_FILE = str(ROOT / 'config' / 'models' / 'planar_2r.yaml')
CYLINDRICAL_FILE = str(ROOT / 'config' / 'models' / 'cylindrical_eq37.yaml')
PLANAR_OTHER = {'l1': 0.9, 'l2': 0.6, 'm1': 10.0, 'm2': 5.0, 'm_p': 3.0, 'g': 9.81}
CYLINDRICAL_OTHER = {'hand_mass': 20.0, 'link_mass': 40.0, 'inertia': 80.0, 'a': 0.7}

# (id, casadi name, casadi params, toc_ros name or file, toc_ros params)
CASES = [
    ('cylindrical-eq37', 'cylindrical', {}, 'cylindrical', {}),
    ('cylindrical-eq36', 'cylindrical', dict(CYLINDRICAL_OTHER, model_variant='eq36'),
     'cylindrical', dict(CYLINDRICAL_OTHER, model_variant='eq36')),
    ('planar_2r', 'planar_2r', {}, 'planar_2r', {}),
    ('planar_2r-gravity', 'planar_2r', PLANAR_OTHER, 'planar_2r', PLANAR_OTHER),
    ('planar_2r-vs-file-kernels', 'planar_2r', PLANAR_OTHER, PLANAR_FILE, PLANAR_OTHER),
    ('planar_2r-file', PLANAR_FILE, PLANAR_OTHER, 'planar_2r', PLANAR_OTHER),
    ('cylindrical-file', CYLINDRICAL_FILE, dict(CYLINDRICAL_OTHER, sign=1.0), 'cylindrical',
     dict(CYLINDRICAL_OTHER, model_variant='eq36')),
]


@pytest.mark.parametrize('ca_name,ca_params,name,params', [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_casadi_model_matches_the_numba_kernels(ca_name, ca_params, name, params):
    f, segments, u_max = cm.casadi_model(ca_name, ca_params)
    model = load_model(name, **params)
    np.testing.assert_array_equal(u_max, model.u_max)
    p = model.packed()
    rng = np.random.default_rng(11)
    for _ in range(100):
        x = rng.uniform(-2.0, 2.0, model.nx)
        if model.joint_kinds[-1] == 'prismatic':
            x[2] = rng.uniform(-0.5, 1.5)
        u = rng.uniform(-1.5, 1.5, model.nu) * model.u_max
        expected = np.zeros(model.nx)
        model.kernels.rhs(x, u, p, expected)
        actual = np.asarray(f(x, u)).reshape(-1)
        np.testing.assert_allclose(actual, expected, rtol=1e-10,
                                   atol=1e-10 * (1.0 + np.max(np.abs(expected))))
        q = x[0::2]
        np.testing.assert_allclose(np.asarray(segments(q)), model.link_segments(q),
                                   rtol=1e-12, atol=1e-12)


def test_casadi_model_refusals():
    with pytest.raises(ValueError, match='unknown model'):
        cm.casadi_model('planar_3r')
    with pytest.raises(ValueError, match='no parameter'):
        cm.casadi_model('planar_2r', {'l3': 1.0})


def test_casadi_model_is_symbolic():
    # The transcription calls f and segments on MX symbols.
    import casadi as ca
    f, segments, _ = cm.casadi_model('planar_2r', {'g': 9.81})
    x, u, q = ca.MX.sym('x', 4), ca.MX.sym('u', 2), ca.MX.sym('q', 2)
    assert f(x, u).shape == (4, 1) and segments(q).shape == (2, 4)
    jac = ca.Function('j', [x, u], [ca.jacobian(f(x, u), ca.vertcat(x, u))])
    assert np.all(np.isfinite(np.asarray(jac(np.ones(4), np.ones(2)))))
