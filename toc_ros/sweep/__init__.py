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
toc-sweep: many minimum-time solves on Dask distributed, results in a Parquet dataset.

spec (the YAML spec and its cases), cases (case -> toc-solve arguments -> Problem), worker
(the Dask task and the warm-up plugin), runner (cluster, batching, streaming), dataset
(Parquet), report (summary and heat map), cli (the toc-sweep command).
"""
