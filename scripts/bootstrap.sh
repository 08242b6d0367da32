#!/usr/bin/env bash
# Idempotent set-up: .venv with pinned dependencies, circle_collision_msgs built
# and installed into it, circle_collision_ros installed (editable) with the ROS
# layout (<venv>/lib/circle_collision_ros/<executable>, share/...).
# Each step re-runs only when its inputs changed (content hashes in .venv/.bootstrap/).
# Usage: scripts/bootstrap.sh [--kernels | --demo | --freeze]  (PYTHON=python3.12: the interpreter)
#   --kernels  also compile every numba kernel into its cache (scripts/test.sh does)
#   --demo     compile the demo's kernels in the background from the moment numba is installed
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV="$ROOT/.venv"
STAMPS="$VENV/.bootstrap"
PY_BOOT=${PYTHON:-python3}
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST

say() { printf '[bootstrap] %s\n' "$*" >&2; }
die() { printf '[bootstrap] error: %s\n' "$*" >&2; exit 1; }

# Hash of file contents (and names), so a step re-runs only when an input changed.
inputs_hash() { (cd "$ROOT" && for f in "$@"; do [ -e "$f" ] && { echo "$f"; cat "$f"; }; done) | sha256sum | cut -d' ' -f1; }
is_current() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
mark() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

# 1. The virtual environment.
if [ ! -x "$VENV/bin/python" ]; then
  command -v "$PY_BOOT" >/dev/null || die "$PY_BOOT not found; install Python 3.10-3.13 or set PYTHON=..."
  "$PY_BOOT" -c 'import sys; sys.exit(not ((3, 10) <= sys.version_info[:2] <= (3, 13)))' \
    || die "$PY_BOOT is $("$PY_BOOT" -V 2>&1); the ROS 2 wheels need Python 3.10-3.13 (set PYTHON=...)"
  say "creating $VENV with $("$PY_BOOT" -V 2>&1)"
  "$PY_BOOT" -m venv "$VENV" || die "python venv failed (on Debian/Ubuntu: apt-get install python3-venv)"
fi
PY="$VENV/bin/python"
PIP=("$PY" -m pip --disable-pip-version-check -q)

# 2. Pinned Python dependencies (ROS 2 Kilted wheels included).
if [ "${1:-}" = "--freeze" ]; then
  "$PY" - > "$ROOT/constraints.txt" <<'PYEOF'
import importlib.metadata as md
rows = {f'{d.metadata["Name"].lower().replace("_", "-")}=={d.version}'
        for d in md.distributions()
        if (d.read_text("INSTALLER") or "").strip() in ("pip", "uv") and d.metadata["Name"]
        and d.metadata["Name"].lower() not in ("pip", "circle-collision-ros")}
print("# Full pin set of the venv; regenerate with: scripts/bootstrap.sh --freeze. Used with pip -c.")
print("\n".join(sorted(rows)))
PYEOF
  say "wrote constraints.txt"; exit 0
fi
# (--demo) The demo's numba kernels (the 2-D exact path; core/warm_up.py needs only numpy and
# numba) compile in the background while the rest installs and the interfaces build: the node
# started next waits for this compile (a lock per job) instead of repeating it.
# Output: build/kernels.log.
KERNELS_STARTED=
start_demo_kernels() {
  [ "${1:-}" = "--demo" ] && [ -z "$KERNELS_STARTED" ] || return 0
  KERNELS_STARTED=1
  mkdir -p "$ROOT/build"
  (cd "$ROOT" && PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" nohup "$PY" -m circle_collision_ros.core.warm_up \
     --jobs exact --dimensions 2 > "$ROOT/build/kernels.log" 2>&1 &)
}

REQS=(requirements.txt requirements-build.txt requirements-test.txt constraints.txt)
h=$(inputs_hash "${REQS[@]}")
if ! is_current deps "$h"; then
  say "installing pinned dependencies"
  # uv (pinned in constraints.txt) installs the same pins as pip in a fraction of the time;
  # pip stays the fallback where uv cannot be had.
  if "${PIP[@]}" install "uv" -c "$ROOT/constraints.txt" 2>/dev/null && [ -x "$VENV/bin/uv" ]; then
    if [ "${1:-}" = "--demo" ]; then  # numba first, so that the kernels compile meanwhile
      "$VENV/bin/uv" pip install --quiet --python "$PY" numpy numba -c "$ROOT/constraints.txt"
      start_demo_kernels "$@"
    fi
    "$VENV/bin/uv" pip install --quiet --python "$PY" -r "$ROOT/requirements.txt" \
      -r "$ROOT/requirements-build.txt" -r "$ROOT/requirements-test.txt" -c "$ROOT/constraints.txt"
  else
    "${PIP[@]}" install -r "$ROOT/requirements.txt" -r "$ROOT/requirements-build.txt" \
      -r "$ROOT/requirements-test.txt" -c "$ROOT/constraints.txt"
  fi
  mark deps "$h"
  rm -f "$STAMPS/msgs"  # a new ROS wheel set means the interfaces must be rebuilt
fi

start_demo_kernels "$@"

# 3. The interface package circle_collision_msgs, built with CMake into the venv: only the
# generators rclpy loads (C and Python; msg_defs/CMakeLists.txt), half the build of all of them.
MSGS_FLAGS=(-DCIRCLE_COLLISION_MSGS_PYTHON_ONLY=ON)
h=$( (inputs_hash $(cd "$ROOT" && find msg_defs -type f | sort); echo "${MSGS_FLAGS[*]}") | sha256sum | cut -d' ' -f1)
if ! is_current msgs "$h"; then
  command -v cmake >/dev/null || die "cmake not found (apt-get install cmake)"
  command -v c++ >/dev/null || command -v g++ >/dev/null || die "no C++ compiler found (apt-get install g++)"
  say "building msg_defs (circle_collision_msgs)"
  BUILD="$ROOT/build/msg_defs"
  rm -rf "$BUILD"
  log="$ROOT/build/msg_defs.log"
  mkdir -p "$ROOT/build"
  if ! (export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
        cmake -S "$ROOT/msg_defs" -B "$BUILD" -DCMAKE_INSTALL_PREFIX="$VENV" \
          -DPython3_EXECUTABLE="$PY" -DBUILD_TESTING=OFF -DCMAKE_BUILD_TYPE=Release "${MSGS_FLAGS[@]}" \
        && cmake --build "$BUILD" -j "$(nproc 2>/dev/null || echo 2)" \
        && cmake --install "$BUILD") > "$log" 2>&1; then
    tail -n 40 "$log" >&2
    die "building msg_defs failed; full log: $log"
  fi
  mark msgs "$h"
fi

# 4. This package, editable (code edits take effect at once), plus the ROS
# layout that colcon would install, linked like `colcon build --symlink-install`:
# every data_files entry of setup.py under <venv>/share/..., and every console
# script under <venv>/lib/circle_collision_ros/ so that `ros2 run` finds it.
h=$(inputs_hash setup.py setup.cfg package.xml resource/circle_collision_ros circle_collision_ros/core/narrow/one_pair_entry.c \
      $(cd "$ROOT" && ls launch/*.launch.py config/*.yaml 2>/dev/null))
if ! is_current package "$h"; then
  say "installing circle_collision_ros (editable) and its ROS layout"
  "${PIP[@]}" install --no-deps --no-build-isolation -e "$ROOT"
  (cd "$ROOT" && "$PY" - "$VENV" <<'PYEOF'
import os, runpy, shutil, sys
import setuptools

venv = sys.argv[1]
setup_kwargs = {}
setuptools.setup = lambda **kw: setup_kwargs.update(kw)  # read setup.py's own declarations
runpy.run_path("setup.py")
package = setup_kwargs["name"]

def link(src: str, dst: str) -> None:
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    if os.path.lexists(dst):
        os.remove(dst)
    os.symlink(src, dst)

for dest, files in setup_kwargs["data_files"]:
    for f in files:
        link(os.path.abspath(f), os.path.join(venv, dest, os.path.basename(f)))

lib = os.path.join(venv, "lib", package)
shutil.rmtree(lib, ignore_errors=True)  # drop executables no longer declared
for spec in setup_kwargs["entry_points"]["console_scripts"]:
    name = spec.split("=")[0].strip()
    link(os.path.join(venv, "bin", name), os.path.join(lib, name))
PYEOF
  )
  mark package "$h"
fi

# 4b. Activation gives a ROS environment, like sourcing a workspace's setup.bash:
# `source .venv/bin/activate` sets AMENT_PREFIX_PATH (ament index: `ros2 run`, `ros2 pkg`,
# `ros2 interface`), CMAKE_PREFIX_PATH, LD_LIBRARY_PATH (the venv's lib/ and the wheels'
# bundled ros_*.libs, for non-Python programs; Python re-execs itself with them anyway),
# ROS_DISTRO/ROS_VERSION/ROS_PYTHON_VERSION, and ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# unless already set (so `ros2` tools see our executables, which default to it).
# `deactivate` restores each variable as it was. The block is rewritten whenever its
# content would change (e.g. a new wheel brings another ros_*.libs directory).
ros_env_block() {
  local site libs d
  site=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  libs='$VIRTUAL_ENV/lib'
  for d in "$site"/ros_*.libs; do [ -d "$d" ] && libs="$libs:\$VIRTUAL_ENV/${d#"$VENV"/}"; done
  local vars="AMENT_PREFIX_PATH CMAKE_PREFIX_PATH LD_LIBRARY_PATH ROS_DISTRO ROS_VERSION ROS_PYTHON_VERSION ROS_AUTOMATIC_DISCOVERY_RANGE"
  echo "# >>> circle_collision_ros ROS environment (written by scripts/bootstrap.sh) >>>"
  echo "_ccr_ros_env_restore () {"
  echo '    [ -n "${_CCR_ROS_ENV_ACTIVE:-}" ] || return 0'
  for v in $vars; do
    echo "    if [ -n \"\${_CCR_OLD_$v+x}\" ]; then $v=\"\$_CCR_OLD_$v\"; export $v; unset _CCR_OLD_$v; else unset $v; fi"
  done
  echo "    unset _CCR_ROS_ENV_ACTIVE"
  echo "}"
  for v in $vars; do
    echo "if [ -n \"\${$v+x}\" ]; then _CCR_OLD_$v=\"\$$v\"; else unset _CCR_OLD_$v; fi"
  done
  echo "_CCR_ROS_ENV_ACTIVE=1"
  echo 'export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"'
  echo 'export CMAKE_PREFIX_PATH="$VIRTUAL_ENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"'
  echo "export LD_LIBRARY_PATH=\"$libs\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}\""
  echo 'export ROS_DISTRO=kilted ROS_VERSION=2 ROS_PYTHON_VERSION=3'
  echo 'export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"'
  echo "# <<< circle_collision_ros ROS environment <<<"
}
ACTIVATE="$VENV/bin/activate"
HOOK='    type _ccr_ros_env_restore >/dev/null 2>\&1 \&\& _ccr_ros_env_restore  # circle_collision_ros'
HOOKED='^    type _ccr_ros_env_restore >/dev/null 2>&1 && _ccr_ros_env_restore  # circle_collision_ros$'
block=$(ros_env_block)
current=$(sed -n '/^# >>> circle_collision_ros ROS environment/,/^# <<< circle_collision_ros ROS environment/p' "$ACTIVATE")
if [ "$current" != "$block" ] || ! grep -q "$HOOKED" "$ACTIVATE"; then
  say "writing the ROS environment into $ACTIVATE"
  sed -i -e '/^# >>> circle_collision_ros ROS environment/,/^# <<< circle_collision_ros ROS environment/d' \
    -e '/_ccr_ros_env_restore.*# circle_collision_ros$/d' "$ACTIVATE"
  # deactivate (also run by activate itself, "nondestructive") restores our variables first.
  sed -i "s|^deactivate () {\$|&\n$HOOK|" "$ACTIVATE"
  grep -q "$HOOKED" "$ACTIVATE" || die "cannot hook deactivate() in $ACTIVATE (unexpected venv activate script)"
  printf '%s\n' "$block" >> "$ACTIVATE"
fi

# 5. (--kernels) Compile every numba kernel job, both dimensions, into numba's on-disk cache,
# in parallel processes (one per core): what the test command needs. A node compiles only
# the paths its parameters reach at its first start (pipeline/kernels.py).
if [ "${1:-}" = "--kernels" ]; then
  (cd "$ROOT" && "$PY" -m circle_collision_ros.pipeline.kernels) || die "compiling the numba kernels failed"
fi
