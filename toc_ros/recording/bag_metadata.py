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
rosbag2's text formats: QoS profile mappings and the YAML layout of its metadata.

The same mappings go into an MCAP channel's ``offered_qos_profiles`` and into
``metadata.yaml``; rosbag2 (yaml-cpp) and rosbags parse them strictly, so every key of the
version-9 mapping is written, policies as rmw's lower-case names, durations as ``{sec, nsec}``,
and the YAML in yaml-cpp's block layout.
"""

from typing import Dict, Iterable, Mapping

import yaml


def _rmw_time(nanoseconds: int) -> Dict[str, int]:
    nanoseconds = int(nanoseconds)
    return {'sec': nanoseconds // 1_000_000_000, 'nsec': nanoseconds % 1_000_000_000}


def _policy_name(policy) -> str:
    name = getattr(policy, 'name', policy)
    return str(name).lower()


def qos_profile_to_dict(profile) -> dict:
    """
    Convert an rclpy QoSProfile (duck-typed) to rosbag2's version-9 QoS mapping.

    Policies are lower-case names (``keep_last``, ``reliable``, ``transient_local``...) and
    durations ``{sec, nsec}``, as rmw_qos_*_policy_to_str and rosbag2_storage write them.
    """
    def duration_ns(value) -> int:
        return int(getattr(value, 'nanoseconds', value))

    return {
        'history': _policy_name(profile.history),
        'depth': int(profile.depth),
        'reliability': _policy_name(profile.reliability),
        'durability': _policy_name(profile.durability),
        'deadline': _rmw_time(duration_ns(profile.deadline)),
        'lifespan': _rmw_time(duration_ns(profile.lifespan)),
        'liveliness': _policy_name(profile.liveliness),
        'liveliness_lease_duration': _rmw_time(duration_ns(profile.liveliness_lease_duration)),
        'avoid_ros_namespace_conventions': bool(profile.avoid_ros_namespace_conventions),
    }


_QOS_POLICIES = ('history', 'reliability', 'durability', 'liveliness')
_QOS_DURATIONS = ('deadline', 'lifespan', 'liveliness_lease_duration')


def complete_qos_profile(profile: Mapping) -> dict:
    """
    Fill what a QoS mapping lacks (e.g. one copied from another writer's bag) with 'unknown'.

    rosbag2 and rosbags expect every key of the version-9 mapping; a missing one makes the
    whole bag unreadable for them. Durations may also be given in nanoseconds.
    """
    result = {}
    for key in ('history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
                'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions'):
        value = profile.get(key)
        if key in _QOS_POLICIES:
            result[key] = _policy_name(value) if value is not None else 'unknown'
        elif key in _QOS_DURATIONS:
            if isinstance(value, Mapping):
                try:
                    value = int(value.get('sec', 0)) * 1_000_000_000 + int(value.get('nsec', 0))
                except (TypeError, ValueError):
                    value = 0
            result[key] = _rmw_time(value if isinstance(value, int) and value >= 0 else 0)
        elif key == 'depth':
            result[key] = value if isinstance(value, int) and value >= 0 else 0
        else:
            result[key] = bool(value)
    return result


class _IndentedDumper(yaml.SafeDumper):
    """Indents sequences under their key, as yaml-cpp (and so rosbag2) does."""

    def increase_indent(self, flow=False, indentless=False):
        return super().increase_indent(flow, False)


def _represent_str(dumper, value):
    style = '"' if value == '' else None  # rosbag2 writes empty strings as ""
    return dumper.represent_scalar('tag:yaml.org,2002:str', value, style=style)


_IndentedDumper.add_representer(
    type(None), lambda dumper, _: dumper.represent_scalar('tag:yaml.org,2002:null', '~'))
_IndentedDumper.add_representer(str, _represent_str)


def dump_yaml(data) -> str:
    """Block-style YAML in rosbag2's layout (key order kept)."""
    return yaml.dump(data, Dumper=_IndentedDumper, default_flow_style=False, sort_keys=False,
                     allow_unicode=True, width=1 << 16)


def qos_profiles_yaml(profiles: Iterable[Mapping]) -> str:
    """Serialise QoS mappings the way rosbag2 stores them in MCAP channel metadata."""
    return dump_yaml([dict(p) for p in profiles])
