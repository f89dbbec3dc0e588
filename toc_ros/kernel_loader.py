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
The numba kernels of a planner's robot model, loaded in the background.

Loading (compiling, or reading the cache) takes seconds to minutes; a node listens meanwhile
and queues its goals until ``ready`` is set.  A new robot model (robot.model or
robot.actuator_lag set at run time) loads its kernels the same way before any goal is solved
with it (``switch``).
"""

import threading
import time

from toc_ros.core import warm_up
from toc_ros.core.models import CylindricalRobot


class KernelLoader:
    """Loads the kernels of the current robot model on a background thread."""

    def __init__(self, model, on_loaded, on_error, clock=time.monotonic):
        """on_loaded(seconds) runs once ready; on_error(exc) when loading failed."""
        self.model = model
        self.ready = threading.Event()
        self.load_s = None          # how long the last load took [s]
        self._on_loaded, self._on_error = on_loaded, on_error
        self._clock = clock
        self._started = clock()

    def start(self):
        """Load the current model's kernels in the background (a pending model: none)."""
        if getattr(self.model, 'pending', False):
            return      # an arm waiting for its URDF: ready once one arrives (switch)
        threading.Thread(target=self._load, name='warm_up', daemon=True).start()

    def switch(self, model):
        """Take a new model; True when its kernels differ and load (not ready meanwhile)."""
        previous, self.model = self.model, model
        if model.kernels is previous.kernels:
            return False
        self.ready.clear()
        self.start()
        return True

    def status(self):
        """Return (ready, the text of the node's ~/ready answer)."""
        if self.ready.is_set():
            return True, f'ready: numba kernels loaded in {self.load_s:.2f} s'
        if getattr(self.model, 'pending', False):
            return False, self.model.reason
        return False, (f'loading the numba kernels ({self._clock() - self._started:.1f} s so '
                       'far); goals are queued until then')

    def _load(self):
        started = self._clock()
        model = self.model
        try:
            if hasattr(model, 'warm_up'):
                model.warm_up()     # a URDF arm: its own solver's kernels
            else:
                # The paper's model: every kernel of the package (None); others: their own.
                warm_up(None if isinstance(model, CylindricalRobot) else [model])
        except Exception as exc:  # noqa: B902 - reported; solves then compile on demand
            self._on_error(exc)
        self.load_s = self._clock() - started
        self.ready.set()
        self._on_loaded(self.load_s)
