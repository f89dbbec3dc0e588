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

"""Append a measured table to benchmarks/RESULTS.md with when, where and how it was made."""

import datetime
import os
import platform

HERE = os.path.dirname(os.path.abspath(__file__))


def append(heading, command, text):
    """Append heading (a Markdown heading line), the command, the time and load, then text."""
    load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else float('nan')
    with open(os.path.join(HERE, 'RESULTS.md'), 'a') as stream:
        stream.write(f'\n\n{heading}\n\n`{command}`, '
                     f'{datetime.datetime.utcnow():%Y-%m-%d %H:%M} UTC, Python '
                     f'{platform.python_version()}, load average {load:.1f} on the shared '
                     f'2-core machine.\n\n{text}\n')
