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
Benchmark scripts and the reference solvers they share with the tests.

A package so that the scripts and the tests import the reference transcriptions by name
(``from benchmarks import reference_solvers``) from the repository root; the scripts still run
as ``python benchmarks/<script>.py``. Not installed (setup.py excludes it): the references
need casadi (extra 'bench') and exist to check toc_ros, not to be part of it.
"""
