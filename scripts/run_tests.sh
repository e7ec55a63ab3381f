#!/usr/bin/env bash
# Sets up, builds and runs every test of normal_fusion (unit tests and rostests).
# Exits non-zero when any test fails.
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${NF_WS:-$repo/.build/ws}"
jobs="${NF_JOBS:-$(nproc)}"

bash "$repo/scripts/build.sh"
cd "$ws/build"
make -j"$jobs" tests >"$ws/build_tests.log" 2>&1 || {
  tail -n 60 "$ws/build_tests.log"
  echo "normal_fusion: building the tests failed (log: $ws/build_tests.log)" >&2
  exit 1
}
# setup.bash reads unset variables: relax -u while sourcing it.
set +u
# shellcheck disable=SC1091
source "$ws/devel/setup.bash"
set -u
ctest --output-on-failure "$@"
