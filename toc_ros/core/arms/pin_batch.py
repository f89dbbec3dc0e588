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
Pinocchio's per-node calls for many nodes in one compiled call (optional, same bits).

The arm solver calls pinocchio.computeABADerivatives once per interval, and from Python about
40 % of each call is the binding's overhead.  pin_batch.cpp loops those calls in C++ against the
headers of the installed Pinocchio and links its own library, so each call is the compiled
code the binding runs: the results are bit for bit the Python loop's (test_arm_pin_batch).

It is compiled once, by ``toc-build-native`` (.ci/setup runs it; a C++ compiler and the
Eigen headers of the cmeel-eigen wheel are needed), into a cache directory (TOC_ROS_CACHE_DIR,
else ~/.cache/toc_ros) under a name that hashes the source, the compiler command and the
Pinocchio install.  Nothing is ever compiled while solving: without the library (not built,
no compiler, TOC_ROS_PIN_BATCH=0) the solver runs the Python loop and `status()` says why.
"""

import argparse
import ctypes
import functools
import hashlib
import os
import pathlib
import subprocess
import sys
import tempfile
import threading
import weakref

import numpy as np
import pinocchio as pin

SOURCE = pathlib.Path(__file__).with_name('pin_batch.cpp')
# Pinocchio's own interface definitions (its CMake targets), and NDEBUG as in the wheel's
# build (the header code compiled here asserts nothing the wheel's does not); -ffp-contract=off:
# no fused multiply-adds in the Euler steps, whose bits must be the Python rollout's.
DEFINES = ('NDEBUG', 'PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION', 'BOOST_MPL_LIMIT_LIST_SIZE=30',
           'BOOST_MPL_LIMIT_VECTOR_SIZE=30', 'BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS',
           'BOOST_FUSION_INVOKE_MAX_ARITY=12')
FLAGS = ('-O2', '-ffp-contract=off', '-fPIC', '-shared', '-std=c++17', '-w')
LIBRARIES = ('pinocchio_default', 'boost_serialization')
CACHED_MODELS = 8
_VOID, _LONG, _DOUBLE = ctypes.c_void_p, ctypes.c_long, ctypes.c_double


class BuildError(RuntimeError):
    """The library could not be compiled (the reason and the compiler's output)."""


def _prefix():
    """Return the install prefix of the imported Pinocchio (with include/pinocchio, lib)."""
    for folder in pathlib.Path(pin.__file__).resolve().parents:
        if (folder / 'include' / 'pinocchio' / 'config.hpp').is_file():
            return folder
    return None


def _eigen_include(prefix):
    for folder in (prefix / 'include' / 'eigen3', pathlib.Path('/usr/include/eigen3')):
        if (folder / 'Eigen' / 'Core').is_file():
            return folder
    return None


def _command(prefix, eigen, output):
    compiler = os.environ.get('CXX', 'c++')
    lib = prefix / 'lib'
    return ([compiler, *FLAGS, *(f'-D{d}' for d in DEFINES), f'-I{prefix / "include"}',
             f'-I{eigen}', str(SOURCE), '-o', str(output), f'-L{lib}',
             *(f'-l{name}' for name in LIBRARIES), f'-Wl,-rpath,{lib}'])


def cache_dir():
    """Directory of the compiled library."""
    root = os.environ.get('TOC_ROS_CACHE_DIR') or os.path.join(
        os.environ.get('XDG_CACHE_HOME') or os.path.expanduser('~/.cache'), 'toc_ros')
    return pathlib.Path(root)


def library_path():
    """Path of the library for this source and Pinocchio install (None without one)."""
    prefix = _prefix()
    eigen = prefix and _eigen_include(prefix)
    if eigen is None:
        return None
    key = hashlib.sha256()
    key.update(SOURCE.read_bytes())
    key.update(repr((_command(prefix, eigen, 'out'), pin.__version__)).encode())
    return cache_dir() / f'pin_batch-{key.hexdigest()[:16]}.so'


def build(verbose=False):
    """Compile the library unless it is there; return its path (BuildError with the reason)."""
    prefix = _prefix()
    if prefix is None:
        raise BuildError(f'no include/pinocchio above {pin.__file__}: the Pinocchio '
                         'install has no headers')
    eigen = _eigen_include(prefix)
    if eigen is None:
        raise BuildError(f'no Eigen headers in {prefix}/include/eigen3 or /usr/include/eigen3 '
                         '(pip install cmeel-eigen)')
    path = library_path()
    if path.is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    # Compiled beside its final name, then renamed: a concurrent build or load never sees a
    # partial file.
    handle, temporary = tempfile.mkstemp(suffix='.so', dir=path.parent)
    os.close(handle)
    command = _command(prefix, eigen, temporary)
    if verbose:
        print(' '.join(command), flush=True)
    try:
        done = subprocess.run(command, capture_output=True, text=True)
    except OSError as error:
        os.unlink(temporary)
        raise BuildError(f'cannot run the C++ compiler {command[0]!r}: {error}') from None
    if done.returncode != 0:
        os.unlink(temporary)
        raise BuildError(f'{command[0]} failed ({done.returncode}):\n{done.stderr[-4000:]}')
    os.replace(temporary, path)
    library.cache_clear()
    return path


@functools.lru_cache(maxsize=None)
def library():
    """(ctypes library or None, reason): the compiled library when it is built and loads."""
    if os.environ.get('TOC_ROS_PIN_BATCH', '1') == '0':
        return None, 'disabled by TOC_ROS_PIN_BATCH=0'
    path = library_path()
    if path is None:
        return None, 'no Pinocchio or Eigen headers to build it against'
    if not path.is_file():
        return None, f'not built ({path} is missing): run toc-build-native'
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as error:
        return None, f'{path} does not load: {error}'
    lib.toc_model_new.restype = _VOID
    lib.toc_model_new.argtypes = [ctypes.c_char_p, _LONG]
    lib.toc_model_free.argtypes = [_VOID]
    lib.toc_model_nv.argtypes = [_VOID]
    lib.toc_data_new.restype = _VOID
    lib.toc_data_new.argtypes = [_VOID]
    lib.toc_data_free.argtypes = [_VOID]
    lib.toc_aba_derivatives.argtypes = [_VOID, _VOID, _LONG] + [_VOID] * 6
    lib.toc_rollout_euler.argtypes = [_VOID, _VOID, _LONG, _VOID, _VOID, _DOUBLE, _VOID]
    return lib, f'compiled ({path})'


def status():
    """One line: whether the solver loops Pinocchio's calls in C++ or in Python, and why."""
    lib, reason = library()
    return ('Pinocchio calls batched in C++: ' if lib is not None
            else 'Pinocchio calls looped in Python: ') + reason


class _Model:
    """A C++ copy of a pinocchio.Model, and the Python copy it was made from."""

    def __init__(self, lib, model):
        if model.nq != model.nv:
            raise RuntimeError('the C++ loop takes models whose configuration is their '
                               f'velocity space (nq {model.nq} != nv {model.nv})')
        self.copy = model.copy()
        stream = pin.serialization.StreamBuffer()
        model.saveToBinary(stream)
        data = stream.tobytes()
        self.handle = lib.toc_model_new(data, len(data))
        if not self.handle or lib.toc_model_nv(self.handle) != model.nv:
            raise RuntimeError('the compiled library did not load the model')
        weakref.finalize(self, lib.toc_model_free, self.handle)


_models = {}
_lock = threading.Lock()


def _model(lib, model):
    # Keyed by the Python object, checked by equality (Model == compares every field, ~1 us):
    # a model changed in place, or a new one at a reused id, is never served a stale copy.
    with _lock:
        found = _models.get(id(model))
        if found is None or not found.copy == model:
            if len(_models) >= CACHED_MODELS:
                _models.pop(next(iter(_models)))
            found = _models[id(model)] = _Model(lib, model)
        return found


class Workspace:
    """The batched calls for one model, with a workspace of its own (one per evaluator)."""

    def __init__(self, lib, model):
        self.model = _model(lib, model)
        self.n = model.nv
        self.lib = lib
        self.handle = lib.toc_data_new(self.model.handle)
        if not self.handle:
            raise RuntimeError('the compiled library could not make a workspace')
        weakref.finalize(self, lib.toc_data_free, self.handle)

    def aba_derivatives(self, states, tau, acc, d_q, d_v, minv):
        """Fill acc (K, n), d_q, d_v, minv (K, n, n) at states (K, 2n) under torques (K, n)."""
        states = np.ascontiguousarray(states, dtype=float)
        tau = np.ascontiguousarray(tau, dtype=float)
        count, n = states.shape[0], self.n
        # The C++ loop writes where it is told: every shape is checked here.
        _check(states, (count, 2 * n), tau, (count, n), acc, (count, n), d_q, (count, n, n),
               d_v, (count, n, n), minv, (count, n, n))
        self.lib.toc_aba_derivatives(self.model.handle, self.handle, count, states.ctypes.data,
                                     tau.ctypes.data, acc.ctypes.data, d_q.ctypes.data,
                                     d_v.ctypes.data, minv.ctypes.data)

    def rollout_euler(self, x0, tau, step):
        """States (K + 1, 2n) of explicit Euler steps of length step under torques (K, n)."""
        x0 = np.ascontiguousarray(x0, dtype=float)
        tau = np.ascontiguousarray(tau, dtype=float)
        _check(x0, (2 * self.n,), tau, (len(tau), self.n))
        states = np.empty((tau.shape[0] + 1, 2 * self.n))
        self.lib.toc_rollout_euler(self.model.handle, self.handle, tau.shape[0], x0.ctypes.data,
                                   tau.ctypes.data, float(step), states.ctypes.data)
        return states


def _check(*pairs):
    for array, shape in zip(pairs[::2], pairs[1::2]):
        if array.shape != shape or array.dtype != np.float64 or not array.flags.c_contiguous:
            raise ValueError(f'pin_batch: expected a C-contiguous float64 array {shape}, got '
                             f'{array.dtype} {array.shape}')


def workspace(model):
    """Return a Workspace for model (None without the library: the Python loop)."""
    lib = library()[0]
    if lib is None:
        return None
    try:
        return Workspace(lib, model)
    except RuntimeError:
        return None         # a model the loop does not take: the Python loop serves it


def main(argv=None):
    """toc-build-native: compile the library (once per Pinocchio install and source)."""
    parser = argparse.ArgumentParser(
        prog='toc-build-native', description="Compile the C++ loop of the arm solver's "
        'Pinocchio calls (same results as the Python loop, faster). Needs a C++ compiler and '
        'the Eigen headers (cmeel-eigen).')
    parser.add_argument('--verbose', action='store_true', help='print the compiler command')
    args = parser.parse_args(argv)
    try:
        path = build(verbose=args.verbose)
    except BuildError as error:
        print(f'toc-build-native: {error}', file=sys.stderr)
        return 1
    print(f'toc-build-native: {path}')
    print(status())
    return 0 if library()[0] is not None else 1


if __name__ == '__main__':
    sys.exit(main())
