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

"""Shared pytest configuration for toc_ros tests."""


def pytest_configure(config):
    # The ament linter plugins register their own markers, but 'linter' comes from ament_lint,
    # which a plain venv does not have.
    for marker in ('linter', 'flake8', 'pep257', 'copyright'):
        config.addinivalue_line('markers', f'{marker}: ament code style check')
    # The quick tier is `pytest -m "not slow"`: node processes, the demo, the CLIs, heavy
    # solves (large N, reference NLPs) and the linters (alone: -m linter) are left to the full run.
    config.addinivalue_line(
        'markers', 'slow: processes, full-size solves or linters (deselect: -m "not slow")')
