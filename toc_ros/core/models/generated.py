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
Where generated kernel modules live and how they are imported (model files, actuator models).

A generated module is written once, atomically, under a content-derived name and imported
from its file, so numba's on-disk cache (toc_ros/core/_numba_cache.py) keeps its machine code
between processes.
"""

import importlib.util
import os
import sys

# The cached wrappers of every generated kernel module: they name its kernels through the
# module object `this` (numba refuses to cache a function that passes a plain global
# dispatcher on to another one), so machine code is cached per model.
WRAPPERS = '''@njit(cache=True, nogil=True)
def rollout(x0, controls, tau, p, method, states):
    """Trajectory from x0 under piecewise-constant controls (N x nu) into states (N+1 x nx)."""
    horizon.rollout(this.rhs, x0, controls, tau, p, method, states)


@njit(cache=True, nogil=True)
def ipm_iterate(ws, n_iter):
    """Run up to n_iter interior-point iterations on workspace ws (see ipm.py)."""
    return ipm.iterate(this.rhs, this.rhs_jac, this.rhs_hess, this.segments, ws, n_iter)


@njit(cache=True, nogil=True)
def ipm_evaluate(ws):
    """Evaluate derivatives and KKT residuals at the current point of ws (see ipm.py)."""
    return ipm.evaluate(this.rhs, this.rhs_jac, this.rhs_hess, this.segments, ws)'''


def cache_root():
    """Directory of the generated model modules (NUMBA_CACHE_DIR or XDG_CACHE_HOME based)."""
    base = os.environ.get('NUMBA_CACHE_DIR')
    if base:
        return os.path.join(base, 'toc_ros-models')
    return os.path.join(os.environ.get('XDG_CACHE_HOME')
                        or os.path.join(os.path.expanduser('~'), '.cache'),
                        'toc_ros', 'models')


def import_file(path, module_name):
    """Import the module at path as module_name (once per process)."""
    if module_name in sys.modules:
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module      # before exec: the wrappers look themselves up
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[module_name]
        raise
    return module


def write_once(path, make_text):
    """Write make_text() to path unless it exists (atomic: concurrent loaders see whole files)."""
    if os.path.exists(path):
        return
    text = make_text()
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f'{path}.{os.getpid()}.tmp'
    with open(tmp, 'w', encoding='utf-8') as stream:
        stream.write(text)
    os.replace(tmp, path)
