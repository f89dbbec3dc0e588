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
Numba's on-disk cache keyed by the core's source code.

numba (cache=True) revalidates a cached kernel against its own file only: after an edit or an
upgrade of another module whose kernels it inlines, it would silently load stale machine code.
Keying the cache directory by a hash of every core source file rules that out.
"""

import hashlib
import os

import numba


def use_source_keyed_cache():
    """Point numba's cache at <base>/toc_ros-<hash of the .py files under toc_ros/core>."""
    here = os.path.dirname(os.path.abspath(__file__))
    digest = hashlib.sha1()
    for folder, dirs, files in sorted(os.walk(here)):
        dirs.sort()
        for name in sorted(files):
            if name.endswith('.py'):
                path = os.path.join(folder, name)
                with open(path, 'rb') as stream:
                    digest.update(os.path.relpath(path, here).encode() + b'\0' + stream.read())
    base = os.environ.get('NUMBA_CACHE_DIR') or os.path.join(
        os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache'),
        'toc_ros', 'numba')
    numba.config.CACHE_DIR = os.path.join(base, 'toc_ros-' + digest.hexdigest()[:16])
