#!/usr/bin/env bash
# Compiles every installed header of normal_fusion (include/normal_fusion/**/*.h)
# the way a downstream catkin package sees it: a CMake project that asks for
# C++14 (the default of Ubuntu 20.04's GCC 9), finds the package through
# find_package(catkin REQUIRED COMPONENTS normal_fusion) in a built workspace
# (whose CFG_EXTRAS must move it to C++17), and compiles one translation unit
# per header, each including its header twice, with -Wall -Wextra -Wpedantic
# -Werror. Exits non-zero when any header fails.
#
# usage: scripts/check_headers.sh [WORKSPACE]
#   WORKSPACE  a catkin workspace where normal_fusion is built
#              (default: NF_WS, else .build/ws in the repository)
# CXX selects the compiler (default: the workspace's).
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${1:-${NF_WS:-$repo/.build/ws}}"
jobs="${NF_JOBS:-$(nproc)}"

if [ ! -f "$ws/devel/setup.bash" ]; then
  echo "normal_fusion header check: no built workspace at $ws" >&2
  exit 1
fi
cxx="${CXX:-$(sed -n 's/^CMAKE_CXX_COMPILER:[A-Z]*=//p' "$ws/build/CMakeCache.txt")}"
check="$ws/header_check"
rm -rf "$check"
mkdir -p "$check/src/units" "$check/build"

count=0
while IFS= read -r header; do
  rel="${header#"$repo/include/"}"
  unit="$check/src/units/$(echo "$rel" | tr '/.' '__').cpp"
  printf '#include <%s>\n#include <%s>\n' "$rel" "$rel" >"$unit"
  count=$((count + 1))
done < <(find "$repo/include/normal_fusion" -name '*.h' | sort)

cat >"$check/src/CMakeLists.txt" <<'EOF'
cmake_minimum_required(VERSION 3.16)
project(normal_fusion_header_check CXX)
# A downstream package on an older default: normal_fusion's CMake extras must
# raise it to C++17.
set(CMAKE_CXX_STANDARD 14)
set(CMAKE_CXX_EXTENSIONS OFF)
find_package(catkin REQUIRED COMPONENTS normal_fusion)
if(NOT CMAKE_CXX_STANDARD EQUAL 17)
  message(FATAL_ERROR "find_package(catkin COMPONENTS normal_fusion) left "
    "CMAKE_CXX_STANDARD at ${CMAKE_CXX_STANDARD}, not 17")
endif()
include_directories(${catkin_INCLUDE_DIRS})
file(GLOB units ${CMAKE_CURRENT_SOURCE_DIR}/units/*.cpp)
add_library(header_check OBJECT ${units})
target_compile_options(header_check PRIVATE -Wall -Wextra -Wpedantic -Werror)
EOF

# setup.bash reads unset variables: relax -u while sourcing it.
set +u
# shellcheck disable=SC1091
source "$ws/devel/setup.bash"
set -u
log="$check/check.log"
if ! (cd "$check/build" &&
  cmake ../src -DCMAKE_CXX_COMPILER="$cxx" -DPYTHON_EXECUTABLE=/usr/bin/python3 \
    -DPython3_EXECUTABLE=/usr/bin/python3 &&
  make -j"$jobs" -k) >"$log" 2>&1; then
  grep -E "error|warning|FATAL" "$log" | head -n 40 || true
  echo "normal_fusion header check: FAILED ($count headers, $cxx; log: $log)" >&2
  exit 1
fi
std="$(grep -o -- '-std=[a-z+0-9]*' "$check/build/CMakeFiles/header_check.dir/flags.make" | sort -u | tr '\n' ' ')"
echo "normal_fusion header check: $count headers compile on their own (${std% }, $(basename "$cxx"), downstream asked for C++14)"
