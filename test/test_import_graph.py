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

"""The package's module-level imports form no cycle, and the core imports nothing of ROS."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / 'toc_ros'
ROS = ('rclpy', 'launch', 'launch_ros', 'std_msgs', 'sensor_msgs', 'geometry_msgs',
       'trajectory_msgs', 'nav_msgs', 'visualization_msgs', 'diagnostic_msgs', 'std_srvs',
       'control_msgs', 'builtin_interfaces', 'rcl_interfaces')


def module_name(path):
    parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def imported_module(package, node):
    """Return the absolute module an ImportFrom node imports from (package: the importer's)."""
    base = node.module or ''
    if not node.level:
        return base
    parent = package.split('.')
    return '.'.join(parent[:len(parent) - node.level + 1] + ([base] if base else []))


def top_level_imports(path):
    """Package modules and names imported at import time (not inside functions)."""
    name = module_name(path)
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    found = set()

    def visit(nodes):
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(node, ast.ClassDef):
                visit(node.body)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = imported_module(package, node)
                found.add(base)
                found.update(f'{base}.{a.name}' for a in node.names)
            else:
                for field in ('body', 'orelse', 'handlers', 'finalbody'):
                    visit(getattr(node, field, []) or [])
    visit(ast.parse(path.read_text()).body)
    return {m for m in found if m.split('.')[0] == 'toc_ros' and m != name}


def exports(path, modules):
    """Map the names a package's __init__ imports from its modules to those modules."""
    package = module_name(path)
    out = {}
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom):
            base = imported_module(package, node)
            for alias in node.names:
                source = f'{base}.{alias.name}'
                out[alias.asname or alias.name] = source if source in modules else base
    return out


def graph():
    """
    Return module -> the package modules it imports at import time.

    A package (its __init__) stands for the modules it takes names from: importing a name
    from toc_ros.core depends on the module defining it, not on every module the package
    gathers (that is how a reader and Python's partial imports see it).
    """
    paths = {module_name(p): p for p in PACKAGE.rglob('*.py')}
    packages = {module_name(p): exports(p, paths) for p in PACKAGE.rglob('__init__.py')}
    edges = {}
    for name, path in paths.items():
        resolved = set()
        for target in top_level_imports(path):
            base, _, leaf = target.rpartition('.')
            if target not in paths and leaf in packages.get(base, {}):
                target = packages[base][leaf]     # a name the package takes from a module
            resolved.add(target)
        # The packages themselves are left out: their names resolved to modules above.
        edges[name] = {t for t in resolved if t in paths and t != name and t not in packages}
    return edges


def find_cycles(edges):
    """Return the cycles a depth-first walk of edges meets (each as a list of modules)."""
    state, cycles = {}, []

    def walk(node, stack):
        state[node] = 'open'
        for nxt in sorted(edges[node]):
            if state.get(nxt) == 'open':
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                walk(nxt, stack + [nxt])
        state[node] = 'done'
    for node in sorted(edges):
        if node not in state:
            walk(node, [node])
    return cycles


def test_the_cycle_search_finds_cycles():
    assert find_cycles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}}) == [['a', 'b', 'c', 'a']]
    assert find_cycles({'a': {'b', 'c'}, 'b': {'c'}, 'c': set()}) == []


def test_the_package_has_no_import_cycle():
    edges = graph()
    assert len(edges) > 50 and 'toc_ros.core.problem' in edges['toc_ros.planner']
    assert not find_cycles(edges)


def test_the_core_imports_no_ros():
    for path in (PACKAGE / 'core').rglob('*.py'):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ''] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                assert name.split('.')[0] not in ROS, f'{path.name} imports {name}'
