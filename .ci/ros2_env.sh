#!/usr/bin/env bash
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

# ros2_env.sh [DIR] - build the real ROS 2 Jazzy user environment (ros2 CLI, launch, colcon)
# with ../shared/ros2-jazzy-env/make_env.sh into DIR (default: <repo>/.ros2env), plus the
# Python packages toc_ros needs at run time that are not ROS packages (numba, mcap,
# matplotlib, sympy for model files; pin, example-robot-data and mujoco for URDF arms: what
# `rosdep install` + `pip install numba mcap pin mujoco` give a ROS user).
#
# Idempotent: a marker file makes a second run a no-op. Without the kit (e.g. a clone with no
# ../shared beside it) it prints why and exits 0; the ROS-CLI tests then skip.
# Then: source DIR/setup.bash   (or let test/test_ros2_cli.py find <repo>/.ros2env itself).
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
KIT=${ROS2_ENV_KIT:-$REPO/../shared/ros2-jazzy-env}
DIR=${1:-$REPO/.ros2env}
MARKER=$DIR/.toc_ros_env_ready
# Runtime deps of toc_ros outside ROS, pinned to the project venv's tested versions; numpy is
# left to make_env.sh's constraints (the ROS wheels' numpy).
EXTRA_DEPS=(numba==0.68.1 mcap==1.6.0 matplotlib==3.11.2 sympy==1.14.0 pin==4.1.0
            example-robot-data==6.0.0 mujoco==4.0.0)

say() { printf '[ros2_env.sh] %s\n' "$*" >&2; }

if [ ! -f "$KIT/make_env.sh" ]; then
  say "no ROS 2 env kit at $KIT: skipping (tests needing ros2/colcon will skip)"
  exit 0
fi
if [ -f "$MARKER" ]; then
  say "already built: $DIR (rm -rf it to rebuild)"
  exit 0
fi

# --- prerequisites make_env.sh checks: CPython 3.11 with headers, cmake, a C++ compiler --------
py_ok() {  # python is CPython 3.11 with Python.h and venv
  "$1" - <<'EOF' >/dev/null 2>&1
import os, sys, sysconfig, venv  # noqa
assert sys.implementation.name == 'cpython' and sys.version_info[:2] == (3, 11)
assert os.path.exists(os.path.join(sysconfig.get_paths()['include'], 'Python.h'))
EOF
}
pick_python() {
  local c
  for c in ${PYTHON:-} python3.11 python3 /usr/bin/python3.11; do
    if command -v "$c" >/dev/null 2>&1 && py_ok "$c"; then command -v "$c"; return 0; fi
  done
  return 1
}

APT_PKGS=()
PY=$(pick_python) || APT_PKGS+=(python3.11-dev python3.11-venv)
command -v cmake >/dev/null 2>&1 || APT_PKGS+=(cmake)
command -v c++ >/dev/null 2>&1 || APT_PKGS+=(g++)
command -v git >/dev/null 2>&1 || APT_PKGS+=(git)
if [ ${#APT_PKGS[@]} -gt 0 ]; then
  if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then
    say "missing prerequisites (${APT_PKGS[*]}) and cannot apt-get install them (not root/apt)"
    exit 1
  fi
  say "installing ${APT_PKGS[*]} with apt-get"
  export DEBIAN_FRONTEND=noninteractive
  # An empty package cache (fresh image) needs an update first; otherwise try without one.
  if ! apt-get install -y -q "${APT_PKGS[@]}" >/dev/null; then
    apt-get update -q >/dev/null
    apt-get install -y -q "${APT_PKGS[@]}" >/dev/null
  fi
  PY=$(pick_python) || { say "no CPython 3.11 with headers even after apt-get"; exit 1; }
fi

# --- build ---------------------------------------------------------------------------
T0=$(date +%s)
say "building ROS 2 Jazzy env in $DIR with $PY (about 2 min)"
# Clear a half-built env from an interrupted run, but never a directory that is something else.
if [ -d "$DIR" ] && [ -n "$(ls -A "$DIR")" ]; then
  if [ ! -d "$DIR/venv" ] && [ ! -f "$DIR/sources.txt" ]; then
    say "$DIR exists and is not a ROS 2 env built by this script: refusing to overwrite"
    exit 1
  fi
  rm -rf "$DIR"
fi
PYTHON=$PY bash "$KIT/make_env.sh" "$DIR"
say "installing toc_ros runtime deps into the env: ${EXTRA_DEPS[*]}"
"$DIR/venv/bin/python" -m pip install -q --disable-pip-version-check \
  -c "$DIR/constraints.txt" "${EXTRA_DEPS[@]}"
touch "$MARKER"
say "done in $(( $(date +%s) - T0 )) s: source $DIR/setup.bash"
