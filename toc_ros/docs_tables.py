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
The parameter table of docs/ros_interface.md, generated from the settings declarations.

Every parameter of solver_node and plant_node is declared once, as a ``setting(...)`` field
of a dataclass (core/settings.py); the nodes declare their ROS parameters from those fields.
This module renders the same fields as a Markdown table and keeps the copy in the docs
between two marker comments current, so that the documentation cannot drift from the code:

    python -m toc_ros.docs_tables            # print the table
    python -m toc_ros.docs_tables --write    # rewrite it in docs/ros_interface.md
    python -m toc_ros.docs_tables --check    # exit 1 when the docs are out of date
"""

import os
import sys

from toc_ros.config import _yaml_value
from toc_ros.nodes.parameters import PLANT_NODE_NAMES, SOLVER_NODE_NAMES, TABLE

BEGIN = ('<!-- BEGIN GENERATED parameters: python -m toc_ros.docs_tables --write '
         '(do not edit by hand) -->')
END = '<!-- END GENERATED parameters -->'
DOC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'docs',
                   'ros_interface.md')


def _cell(text):
    """Markdown table cell: a pipe would end the cell, a newline the row."""
    return str(text).replace('|', '\\|').replace('\n', ' ')


def _range(parameter):
    if parameter.choices:
        return ', '.join(f'`{c}`' for c in parameter.choices)
    if parameter.low is not None and parameter.high is not None:
        return f'{parameter.low:g} – {parameter.high:g}'
    return ''


def _nodes(name):
    return ', '.join(node for node, names in (('solver', SOLVER_NODE_NAMES),
                                              ('plant', PLANT_NODE_NAMES)) if name in names)


def parameter_table():
    """Return the Markdown table of every solver_node and plant_node parameter."""
    names = list(dict.fromkeys(SOLVER_NODE_NAMES + PLANT_NODE_NAMES))
    rows = ['| parameter | node | type | default | unit | range / choices | description |',
            '|---|---|---|---|---|---|---|']
    for name in names:
        parameter = TABLE[name]
        rows.append('| ' + ' | '.join(_cell(text) for text in (
            f'`{name}`', _nodes(name), parameter.ros_type,
            f'`{_yaml_value(parameter.default)}`', parameter.unit, _range(parameter),
            parameter.description)) + ' |')
    return '\n'.join(rows) + '\n'


def render(document):
    """Return document with the text between the markers replaced by the current table."""
    head, begin, rest = document.partition(BEGIN)
    _, end, tail = rest.partition(END)
    if not begin or not end:
        raise ValueError(f'the document has no {BEGIN!r} ... {END!r} markers')
    return head + BEGIN + '\n\n' + parameter_table() + '\n' + END + tail


def main(argv=None):
    """Print, write (--write) or check (--check) the table: python -m toc_ros.docs_tables."""
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        sys.stdout.write(parameter_table())
        return 0
    if argv not in (['--write'], ['--check']):
        print('usage: python -m toc_ros.docs_tables [--write | --check]', file=sys.stderr)
        return 2
    with open(DOC) as stream:
        current = stream.read()
    try:
        text = render(current)
    except ValueError as exc:
        print(f'{DOC}: {exc}', file=sys.stderr)
        return 2
    if argv == ['--write']:
        if text != current:
            with open(DOC, 'w') as stream:
                stream.write(text)
        return 0
    same = text == current
    print(f'{DOC} is ' + ('up to date' if same else 'out of date: run python -m '
                          'toc_ros.docs_tables --write'))
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
