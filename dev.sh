#!/usr/bin/env bash
# One entry point for newcomers, CI and developers. Every command first sets up
# everything (idempotent: a second run skips work already done):
#   1. a project-local virtual environment .venv with ROS 2 Jazzy from PyPI wheels,
#      numpy, scipy, the test and lint tools (exact versions: requirements.txt);
#   2. the CMake path fix-up the ROS wheels need for colcon builds (../shared/ros-wheels.md);
#   3. `colcon build --symlink-install` into install/ of this ament_python package, of
#      the ament_cmake interface package rigid_body_sim_interfaces in interfaces/, and of
#      the standard interface packages in vendor/ that the environment lacks (tf2_msgs).
#
# Usage:
#   ./dev.sh run [SCENE.yaml] [--ros-args ...]   start the node (default scene:
#                                         config/default_scene.yaml) until Ctrl-C
#   ./dev.sh echo [BODY] [options]        print a body's state as the node publishes it
#   ./dev.sh scene [SCENE.yaml] [options] step a scene without ROS and print a summary
#   ./dev.sh experiment SCENE --schedule S --bag OUT   a scripted run in lockstep, to a bag
#   ./dev.sh record -o OUT [options]      record a running node's topics to a bag
#   ./dev.sh plot BAG [-o out.png]        plot a bag
#   ./dev.sh test [pytest args]           run the whole test suite
#   ./dev.sh bench [--quick]              run the benchmarks (installs bench/requirements.txt:
#                                         MuJoCo, the Panda URDF, Pinocchio; tables and plots
#                                         in bench/out/, all the tables in docs/performance.md)
#   ./dev.sh python [ARGS]                python in the environment (with bench/requirements.txt),
#                                         e.g. one benchmark: ./dev.sh python bench/node.py
#   ./dev.sh setup                        set up only
set -euo pipefail

cd "$(dirname "$0")"
ROOT=$(pwd)
VENV="$ROOT/.venv"
PYTHON=${PYTHON:-python3}

say() { echo "[dev.sh] $*" >&2; }

hash_of() { cat "$@" | sha256sum | cut -d' ' -f1; }

setup_venv() {
    if [ ! -x "$VENV/bin/python" ]; then
        local version
        version=$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
        case "$version" in
            3.10|3.11|3.12|3.13) ;;
            *) say "ROS 2 Jazzy wheels exist for Python 3.10-3.13; $PYTHON is $version"; exit 1 ;;
        esac
        say "creating $VENV with $PYTHON ($version)"
        "$PYTHON" -m venv "$VENV"
    fi
    local want have
    want=$(hash_of requirements.txt)
    have=$(cat "$VENV/.requirements.sha256" 2>/dev/null || true)
    if [ "$want" != "$have" ]; then
        say "installing requirements.txt into .venv (about 1 minute the first time)"
        "$VENV/bin/python" -m pip install --disable-pip-version-check -q -r requirements.txt
        echo "$want" > "$VENV/.requirements.sha256"
        rm -f "$VENV/.cmake-paths-fixed"
    fi
}

fix_cmake_paths() {
    # The wheels' exported CMake files name include directories of the machine that
    # built them; point them at this interpreter's (needed to build interface packages).
    [ -f "$VENV/.cmake-paths-fixed" ] && return 0
    local py_inc np_inc
    py_inc=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
    np_inc=$("$VENV/bin/python" -c 'import numpy; print(numpy.get_include())')
    if [ -d "$VENV/share" ]; then
        grep -rlF '/opt/python/cp311-cp311' "$VENV/share" 2>/dev/null | while read -r f; do
            sed -i \
                -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g" \
                -e "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g" "$f"
        done
    fi
    touch "$VENV/.cmake-paths-fixed"
}

vendored_to_build() {
    # vendor/<pkg>/ stands in for a standard interface package the wheels lack (tf2_msgs).
    # Print the ones to build: those whose name is not in the ament index of the environment
    # colcon builds against and the node runs in (the venv; build and activate set
    # AMENT_PREFIX_PATH to it alone), so that a real package, once installed there, wins.
    # Our own install/ is never consulted: it would find the stand-in itself.
    local dir pkg
    for dir in vendor/*/; do
        [ -f "$dir/package.xml" ] || continue
        pkg=$(basename "$dir")
        if ! grep -q "<name>$pkg</name>" "$dir/package.xml"; then
            say "vendor/$pkg/package.xml: the package must be named after its folder, $pkg"
            exit 1
        fi
        [ -e "$VENV/share/ament_index/resource_index/packages/$pkg" ] || echo "$pkg"
    done
}

build() {
    # Rebuild when a package's metadata or its list of installed files changes, a message
    # or service definition changes, or the wheels the interface code is generated and
    # compiled against (requirements.txt); with --symlink-install, edits to Python sources
    # and config files need no rebuild. install/ holds symlinks into build/: rebuild when
    # either is missing. A vendored package is part of the build while the environment
    # lacks it (vendored_to_build): its files and the list of them are inputs too, and one
    # no longer needed is removed from build/ and install/ (install/setup.sh sources every
    # package it finds in install/, so a stale one would shadow the real one).
    local want have pkg dir list complete=1 vendored=() paths=(. interfaces)
    list=$(vendored_to_build)
    read -r -a vendored <<< "${list//$'\n'/ }"
    for dir in vendor/*/; do
        [ -f "$dir/package.xml" ] || continue
        pkg=$(basename "$dir")
        case " ${vendored[*]-} " in *" $pkg "*) continue ;; esac
        if [ -e "$ROOT/install/$pkg" ] || [ -e "$ROOT/build/$pkg" ]; then
            say "the environment has $pkg: removing the vendored one from build/ and install/"
            rm -rf "${ROOT:?}/install/$pkg" "${ROOT:?}/build/$pkg"
        fi
    done
    for pkg in ${vendored[@]+"${vendored[@]}"}; do
        paths+=("vendor/$pkg")
    done
    want=$( (cat requirements.txt package.xml setup.py setup.cfg \
                 interfaces/package.xml interfaces/CMakeLists.txt interfaces/msg/* interfaces/srv/*
             ls config launch resource interfaces/msg interfaces/srv
             for pkg in ${vendored[@]+"${vendored[@]}"}; do
                 find "vendor/$pkg" -type f | LC_ALL=C sort
                 find "vendor/$pkg" -type f -print0 | LC_ALL=C sort -z | xargs -0 cat
             done) | sha256sum | cut -d' ' -f1)
    have=$(cat "$ROOT/install/.build.sha256" 2>/dev/null || true)
    for pkg in rigid_body_sim rigid_body_sim_interfaces ${vendored[@]+"${vendored[@]}"}; do
        [ -d "$ROOT/build/$pkg" ] && [ -d "$ROOT/install/$pkg" ] || complete=0
    done
    if [ "$want" != "$have" ] || [ ! -f "$ROOT/install/setup.sh" ] || [ "$complete" = 0 ]; then
        say "colcon build${vendored[0]+ (vendored: ${vendored[*]})}"
        (
            export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
            "$VENV/bin/colcon" --log-base "$ROOT/log" build --symlink-install \
                --base-paths "${paths[@]}" \
                --build-base "$ROOT/build" --install-base "$ROOT/install" \
                --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" >&2
        )
        echo "$want" > "$ROOT/install/.build.sha256"
    fi
}

bench_requirements() {
    # Benchmark-only dependencies (MuJoCo for bench/mujoco_peer.py; example-robot-data and
    # Pinocchio too for bench/robot_panda.py, about 600 MB with MuJoCo): installed by
    # ./dev.sh bench only, never by setup, run or test; again when either file changes.
    local want have
    want=$(hash_of requirements.txt bench/requirements.txt)
    have=$(cat "$VENV/.bench-requirements.sha256" 2>/dev/null || true)
    if [ "$want" != "$have" ]; then
        say "installing bench/requirements.txt into .venv (MuJoCo, example-robot-data, pin)"
        "$VENV/bin/python" -m pip install --disable-pip-version-check -q -r bench/requirements.txt
        echo "$want" > "$VENV/.bench-requirements.sha256"
    fi
}

activate() {
    # shellcheck disable=SC1091
    source "$VENV/bin/activate"
    # install/setup.sh is POSIX sh and reads unset variables. It prepends the install
    # prefixes to AMENT_PREFIX_PATH; export the venv first (bash keeps what a sourced file
    # exports over a `VAR=value . file` prefix only inside a function).
    set +u
    export AMENT_PREFIX_PATH="$VENV"
    COLCON_CURRENT_PREFIX="$ROOT/install" . "$ROOT/install/setup.sh"
    set -u
}

compile_kernels() {
    # numba compiles the core's kernels at their first call and caches them next to the
    # sources: do it here, once (about 330 s on 2 cores, the contact steps' kernel about
    # 200 of them), not in the node's first start or a test.
    if ! ls "$ROOT"/rigid_body_sim/core/kernels/__pycache__/*.nbi >/dev/null 2>&1; then
        say "compiling the step kernels (numba, about 5 minutes the first time)"
    fi
    python -m rigid_body_sim.core.warmup >&2
}

setup() {
    setup_venv
    fix_cmake_paths
    build
    activate
    compile_kernels
}

cmd=${1:-}
[ $# -gt 0 ] && shift
case "$cmd" in
    setup) setup ;;
    run)
        setup
        if [ $# -gt 0 ] && [ "${1#-}" = "$1" ]; then
            scene=$(realpath "$1")
            shift
            set -- --ros-args -p "scene:=$scene" "$@"
        fi
        exec "$ROOT/install/rigid_body_sim/lib/rigid_body_sim/sim_node" "$@"
        ;;
    echo)
        setup
        exec "$ROOT/install/rigid_body_sim/lib/rigid_body_sim/echo_body" "$@"
        ;;
    scene)
        setup
        exec "$ROOT/install/rigid_body_sim/lib/rigid_body_sim/rigid_body_sim_run" "$@"
        ;;
    experiment|record|plot)
        setup
        exec "$ROOT/install/rigid_body_sim/lib/rigid_body_sim/$cmd" "$@"
        ;;
    test)
        setup
        exec python -m pytest "$@"
        ;;
    bench)
        setup
        bench_requirements
        exec python bench/run_all.py "$@"
        ;;
    python)
        setup
        bench_requirements
        exec python "$@"
        ;;
    *)
        sed -n '2,24p' "$0" | sed 's/^# \{0,1\}//'
        exit 2
        ;;
esac
