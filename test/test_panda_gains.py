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


"""config/panda.yaml's PD is stable at plant_node's 1 kHz step over the whole workspace."""

from pathlib import Path

import numpy as np
import pytest
import yaml

pin = pytest.importorskip('pinocchio')
CONFIG = Path(__file__).resolve().parents[1] / 'config' / 'panda.yaml'


def test_the_d_term_is_stable_at_the_plants_step_everywhere():
    # The D term acts once per step on the velocity: the loop q'' = -M(q)^-1 Kd q' stepped
    # at dt diverges when dt * |eig(M^-1 Kd)| > 2; require a margin (1.8) at 3000 random
    # configurations within the joint limits.
    from toc_ros.core.arms import load_arm
    try:
        arm = load_arm('panda')
    except Exception as exc:      # noqa: B902 - example-robot-data missing
        pytest.skip(str(exc))
    plant = yaml.safe_load(CONFIG.read_text())['plant_node']['ros__parameters']
    assert list(plant['joint_names']) == list(arm.joint_names)
    kd = np.diag(plant['kd'])
    dt = 1.0 / plant.get('integration_rate', 1000.0)
    data, rng = arm.model.createData(), np.random.default_rng(7)
    worst = 0.0
    for _ in range(3000):
        mass = pin.crba(arm.model, data, rng.uniform(arm.lower, arm.upper))
        mass = np.triu(mass) + np.triu(mass, 1).T
        worst = max(worst, dt * np.max(np.abs(np.linalg.eigvals(np.linalg.solve(mass, kd)))))
    assert worst < 1.8, worst
    # The gains it replaced (kd 50 on the shoulder and elbow) were unstable there.
    old = np.diag([50.0, 50.0, 50.0, 50.0, 20.0, 15.0, 5.0])
    q = np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0])       # joints 1 and 3 in line
    mass = pin.crba(arm.model, data, q)
    mass = np.triu(mass) + np.triu(mass, 1).T
    assert dt * np.max(np.abs(np.linalg.eigvals(np.linalg.solve(mass, old)))) > 2.0
