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
The online estimate that replan cycles and goals plan with (replan.estimate).

``OnlineEstimate`` is fed by the measured states (a node's joint_states) and read by the
planner; the model it gives follows the estimator (core/estimation.py) through an
``EstimateHold``: it changes only when a parameter moved enough, so that successive cycles
solve the same problem and warm-start from each other.
"""

import threading

from toc_ros.core.estimation import estimate_text, ParameterEstimator
from toc_ros.core.models import ModelError, with_actuator_lag

# The planned model follows the online estimate when a parameter moved by more than this
# (relative) from the one planned with.
ESTIMATE_CHANGE = 0.01


class EstimateHold:
    """
    The online estimate the cycles plan with, changed only when it moved enough.

    The model planned with changes only when a parameter moved by more than change (relative)
    from the one held: successive cycles then solve the same problem, and each warm start (the
    previous cycle's optimum) stays nearly optimal.
    """

    def __init__(self, change=ESTIMATE_CHANGE):
        self.change = change
        self.values = None       # the estimate planned with
        self.model = None        # its model

    def clear(self):
        """Forget the held estimate (new settings, no estimate)."""
        self.values, self.model = None, None

    def moved(self, values):
        """Tell whether values differ from the held estimate by more than the change."""
        held = self.values
        return held is None or held.keys() != values.keys() or any(
            abs(values[k] - held[k]) > self.change * abs(held[k]) for k in values)

    def update(self, values, build):
        """
        Return the model to plan with for the estimate values (None: no model).

        build(values) makes the model of an estimate (None when it cannot); it is called only
        when the estimate moved.
        """
        if values is None:
            self.clear()
            return None
        if self.moved(values):
            model = build(values)
            if model is None:
                return None
            self.values, self.model = dict(values), model
        return self.model


class OnlineEstimate:
    """
    The online estimate of the replan cycles: fed by measured states, read by the cycles.

    Thread-safe.  A new joint model, estimated names or window starts a new estimator; the
    model the cycles plan with follows the estimate through an EstimateHold.
    """

    def __init__(self, change=ESTIMATE_CHANGE):
        self._lock = threading.Lock()
        self._estimator = None
        self._key = None
        self._refused = ''          # why the estimator of the current key could not be made
        self._hold = EstimateHold(change)

    def reset(self):
        """Forget every sample and the held estimate (new estimation settings)."""
        with self._lock:
            self._estimator, self._key, self._refused = None, None, ''
            self._hold.clear()

    def add(self, joint_model, names, window, t, state, effort):
        """Add one sample: joint state [q1, dq1, ...] at time t [s] with the applied efforts."""
        key = (joint_model, tuple(names), float(window))
        with self._lock:
            if key != self._key:      # new robot data or estimation settings
                self._key = key
                self._hold.clear()
                try:
                    self._estimator, self._refused = ParameterEstimator(*key), ''
                except ModelError as exc:   # e.g. a URDF arm loaded after the names were set
                    self._estimator, self._refused = None, str(exc)
            if self._estimator is not None:
                self._estimator.add(t, state[0::2], state[1::2], effort)

    def model(self, joint_model, actuator_lag):
        """
        Return (model with the online estimate or None, its text or the reason for none).

        joint_model: the current robot's joint model (an estimator of another is ignored);
        actuator_lag: the lag [s] the planned model assumes.
        """
        with self._lock:
            estimator = self._estimator
            if estimator is None or estimator.model_ != joint_model:
                return None, self._refused or 'no samples yet'

            def build(values):
                model = estimator.model(values)
                return None if model is None else with_actuator_lag(model, actuator_lag)
            model = self._hold.update(estimator.estimate(), build)
            if model is None:
                return None, estimator.status
            return model, estimate_text(self._hold.values)
