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
Complete message definitions (schema text) of ROS 2 types, as rosbag2 stores them.

Mirrors rosbag2_cpp's LocalMessageDefinitionSource, so readers that parse rosbag2 schemas
(Foxglove, mcap-ros2-support, rosbags) parse ours the same way:

* ``ros2msg``: the type's own ``.msg`` text verbatim (comments, constants, defaults, bounds
  kept), then for every dependency, depth first in sorted order and each once, a newline, a
  line of 80 ``=``, a line ``MSG: <dependency as named in the .msg>`` and that type's text.
* ``ros2idl`` fallback when a ``.msg`` file is missing: every definition, the root included,
  preceded by the ``=`` line and ``IDL: pkg/msg/Type``.

The files are read from ``<prefix>/share/<pkg>/msg/`` of the ament index (AMENT_PREFIX_PATH).
"""

import json
import os
import re
from typing import Callable, Dict, List, NamedTuple, Optional, Set

DELIMITER = '=' * 80 + '\n'

# Same patterns as rosbag2: a field type at the start of a line ("foo_msgs/Bar" in
# "foo_msgs/Bar[] bar"), and an include in an .idl file.
_MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_IDL_INCLUDE = re.compile(r'(?:^|\n)#include\s+(?:"|<)([a-zA-Z0-9_/]+)\.idl(?:"|>)')

# rosbag2's list, plus wstring, which it misses (it would look for a file pkg/msg/wstring.msg).
PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'})

_NAME = r'[a-zA-Z][a-zA-Z0-9_]*'
_TYPE_NAME = re.compile(rf'^({_NAME})/(?:({_NAME})/)?({_NAME})$')

# Definitions nest only a few levels deep; this bounds a (broken) cyclic definition.
MAX_DEPTH = 50


class MessageDefinitionError(LookupError):
    """A type name is malformed or its definition files cannot be found."""


class MessageDefinition(NamedTuple):
    """Complete definition of one type: ``encoding`` is ros2msg, ros2idl or unknown."""

    type_name: str
    encoding: str
    text: str


def split_type_name(type_name: str):
    """Split ``pkg/msg/Type`` or ``pkg/Type`` into (package, namespace, type)."""
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise MessageDefinitionError(
            f'message type name {type_name!r} is not of the form pkg/msg/Type')
    package, namespace, name = match.groups()
    return package, namespace or 'msg', name


def msg_dependencies(text: str, package: str) -> List[str]:
    """Return the sorted non-primitive field types of a ``.msg`` text, as rosbag2 finds them."""
    deps: Set[str] = set()
    for match in _MSG_FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in PRIMITIVE_TYPES:
            continue
        deps.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(deps)


def idl_dependencies(text: str) -> List[str]:
    """Return the sorted ``#include``d types of an ``.idl`` text."""
    return sorted({m.group(1) for m in _IDL_INCLUDE.finditer(text)})


def share_directories() -> List[str]:
    """Return ``<prefix>/share`` for every prefix of AMENT_PREFIX_PATH, in order."""
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '')
    return [os.path.join(p, 'share') for p in prefixes.split(os.pathsep) if p]


def _package_share(package: str) -> Optional[str]:
    try:
        from ament_index_python.packages import get_package_share_directory
        from ament_index_python.packages import PackageNotFoundError
    except ImportError:  # pragma: no cover - ament_index_python ships with rclpy
        get_package_share_directory = None
    if get_package_share_directory is not None:
        try:
            return get_package_share_directory(package)
        except (PackageNotFoundError, LookupError, ValueError):
            pass
    # Not registered in the ament index (e.g. a plain install): look in the share folders.
    for share in share_directories():
        candidate = os.path.join(share, package)
        if os.path.isdir(candidate):
            return candidate
    return None


def default_loader(package: str, namespace: str, name: str, extension: str) -> str:
    """Read ``<share of package>/<namespace>/<name><extension>``."""
    share = _package_share(package)
    if share is None:
        raise MessageDefinitionError(
            f'package {package!r} not found in the ament index '
            f'(AMENT_PREFIX_PATH={os.environ.get("AMENT_PREFIX_PATH", "")!r})')
    path = os.path.join(share, namespace, name + extension)
    try:
        with open(path, encoding='utf-8') as stream:
            return stream.read()
    except OSError as error:
        raise MessageDefinitionError(
            f'definition of {package}/{namespace}/{name} not readable: {error}') from error


Loader = Callable[[str, str, str, str], str]


class MessageDefinitionSource:
    """Builds and caches complete definitions; ``loader`` reads one definition file."""

    def __init__(self, loader: Loader = default_loader):
        self._loader = loader
        self._texts: Dict[tuple, str] = {}
        self._full: Dict[str, MessageDefinition] = {}

    def _text(self, type_name: str, extension: str) -> str:
        key = (type_name, extension)
        if key not in self._texts:
            package, namespace, name = split_type_name(type_name)
            self._texts[key] = self._loader(package, namespace, name, extension)
        return self._texts[key]

    def _expand(self, root: str, extension: str) -> str:
        seen: Set[str] = set()
        tag = 'MSG: ' if extension == '.msg' else 'IDL: '

        def append(type_name: str, depth: int) -> str:
            if depth <= 0:
                raise MessageDefinitionError(
                    f'definition of {root} nests deeper than {MAX_DEPTH} levels (cycle?)')
            text = self._text(type_name, extension)
            if extension == '.msg':
                deps = msg_dependencies(text, split_type_name(type_name)[0])
            else:
                deps = idl_dependencies(text)
            parts = [text]
            for dep in deps:
                if dep not in seen:
                    seen.add(dep)
                    parts.append('\n' + DELIMITER + tag + dep + '\n' + append(dep, depth - 1))
            return ''.join(parts)

        if extension == '.msg':
            return append(root, MAX_DEPTH)
        return DELIMITER + tag + root + '\n' + append(root, MAX_DEPTH)

    def get(self, type_name: str) -> MessageDefinition:
        """
        Return the complete definition of ``type_name`` (e.g. ``std_msgs/msg/String``).

        Falls back to IDL when some ``.msg`` file is missing, as rosbag2 does.
        Raises MessageDefinitionError when neither form is available.
        """
        if type_name not in self._full:
            split_type_name(type_name)  # reject malformed names with a clear message
            try:
                definition = MessageDefinition(
                    type_name, 'ros2msg', self._expand(type_name, '.msg'))
            except MessageDefinitionError as msg_error:
                try:
                    definition = MessageDefinition(
                        type_name, 'ros2idl', self._expand(type_name, '.idl'))
                except MessageDefinitionError:
                    raise msg_error from None
            self._full[type_name] = definition
        return self._full[type_name]


_DEFAULT_SOURCE = MessageDefinitionSource()


def full_definition(type_name: str) -> MessageDefinition:
    """Complete definition of ``type_name`` from the installed ``.msg`` (or ``.idl``) files."""
    return _DEFAULT_SOURCE.get(type_name)


def type_description_hash(type_name: str) -> str:
    """
    Return the ``RIHS01_...`` type hash of ``type_name`` from its generated ``.json`` file.

    Empty string when unknown (rosbag2 writes an empty hash too in that case).
    """
    try:
        package, namespace, name = split_type_name(type_name)
        text = default_loader(package, namespace, name, '.json')
        full_name = f'{package}/{namespace}/{name}'
        for entry in json.loads(text).get('type_hashes', []):
            if entry.get('type_name') == full_name:
                return str(entry.get('hash_string', ''))
    except (MessageDefinitionError, ValueError, AttributeError):
        pass  # no type description installed: rosbag2 records an empty hash then too
    return ''
