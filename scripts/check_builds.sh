#!/usr/bin/env bash
# Builds normal_fusion (the whole package, catkin_make) in other
# configurations, each in its own workspace .build/ws-NAME: other compilers,
# and the default compiler without OpenCV contrib. Fails on any compiler
# warning in the package's own sources; runs the ROS-free unit tests of the
# builds named in NF_UNIT_TEST_BUILDS. Called by scripts/run_tests.sh.
#
# usage: scripts/check_builds.sh [NAME=COMPILER[,CMAKE_ARG...] ...]
#   default: gcc11-nocontrib=g++-11,-DNF_WITH_OPENCV_CONTRIB=OFF
#            clang14=clang++-14
#   (g++-11 also checks the build without OpenCV contrib: one build fewer
#   keeps CI within its time; GCC 12 and clang++-14 build the contrib parts.)
# NF_UNIT_TEST_BUILDS: names whose unit tests run (default: clang14)
# scripts/check_builds.sh --warnings LOG...: only the warning check, on the
# logs of another build (run_tests.sh uses it for the default build).
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
jobs="${NF_JOBS:-$(nproc)}"
unit_test_builds=" ${NF_UNIT_TEST_BUILDS-clang14} "

# Prints the compiler warnings located in the package's own files (the
# repository, or its link in a workspace's src/) found in the given build
# logs; returns 1 when there is any.
own_warnings() {
  local found
  found="$(grep -hE "^(${repo}|[^ :]*/src/normal_fusion)/[^ :]+:[0-9]+(:[0-9]+)?: warning:" "$@" |
    sort -u || true)"
  if [ -n "$found" ]; then
    echo "$found"
    return 1
  fi
  return 0
}

if [ "${1:-}" = "--warnings" ]; then
  shift
  if ! own_warnings "$@"; then
    echo "normal_fusion: compiler warnings in the package's sources (above)" >&2
    exit 1
  fi
  exit 0
fi

builds=("$@")
if [ ${#builds[@]} -eq 0 ]; then
  builds=(gcc11-nocontrib=g++-11,-DNF_WITH_OPENCV_CONTRIB=OFF clang14=clang++-14)
fi

status=0
for entry in "${builds[@]}"; do
  name="${entry%%=*}"
  IFS=',' read -r -a spec <<<"${entry#*=}"
  cxx="${spec[0]}"
  cmake_args=("${spec[@]:1}")
  ws="$repo/.build/ws-$name"
  start=$(date +%s)
  if ! command -v "$cxx" >/dev/null; then
    echo "normal_fusion: $cxx not found (scripts/setup.sh installs it)" >&2
    status=1
    continue
  fi
  echo "== normal_fusion: $name, $cxx ($("$cxx" --version | head -n 1))${cmake_args[*]:+ ${cmake_args[*]}}, in $ws"
  if ! NF_WS="$ws" bash "$repo/scripts/build.sh" -DCMAKE_CXX_COMPILER="$cxx" \
    ${cmake_args[@]+"${cmake_args[@]}"}; then
    status=1
    continue
  fi
  logs=("$ws/build.log")
  if [[ "$unit_test_builds" == *" $name "* ]]; then
    # The ROS-free unit tests: one gtest per test/{core,io,tools,eval}/test_*.cpp
    # that this configuration builds.
    targets="$(make -C "$ws/build" help | sed -n 's/^\.\.\. \([^ ]*\).*/\1/p')"
    units=()
    for source in "$repo"/test/{core,io,tools,eval}/test_*.cpp; do
      unit="$(basename "$source" .cpp)"
      if grep -qx "$unit" <<<"$targets"; then units+=("$unit"); fi
    done
    if ! make -C "$ws/build" -j"$jobs" "${units[@]}" >"$ws/build_tests.log" 2>&1; then
      tail -n 40 "$ws/build_tests.log"
      echo "normal_fusion: building the unit tests of $name failed (log: $ws/build_tests.log)" >&2
      status=1
      continue
    fi
    logs+=("$ws/build_tests.log")
    pattern="$(IFS='|'; echo "${units[*]}")"
    if ! (cd "$ws/build" && ctest --output-on-failure -R "_gtest_(${pattern})\$"); then
      echo "normal_fusion: unit tests of $name failed" >&2
      status=1
    fi
  fi
  if ! own_warnings "${logs[@]}"; then
    echo "normal_fusion: compiler warnings in the package's sources in $name (above)" >&2
    status=1
  fi
  echo "normal_fusion: $name done in $(( $(date +%s) - start )) s"
done
exit $status
