#!/usr/bin/env bash
# Sets up, builds and runs every test of normal_fusion (unit tests and rostests),
# then the platform checks: no compiler warning in the package's sources,
# every installed header compiled as a downstream C++14 package would
# (scripts/check_headers.sh), catkin_lint, and the package built with g++-11
# without OpenCV contrib and with clang++-14, the latter's unit tests run
# (scripts/check_builds.sh). Exits non-zero when any test or check fails.
# Arguments go to ctest; NF_EXTRA_BUILDS=0 leaves out the other builds.
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

echo "== platform checks"
bash "$repo/scripts/check_builds.sh" --warnings "$ws/build.log" "$ws/build_tests.log"
bash "$repo/scripts/check_headers.sh" "$ws"
# --strict: warnings fail too (the default level shows errors and warnings).
lint="$(catkin_lint --strict "$repo" 2>&1)" || {
  echo "$lint"
  echo "normal_fusion: catkin_lint reports problems" >&2
  exit 1
}
echo "normal_fusion: catkin_lint clean"
if [ "${NF_EXTRA_BUILDS:-1}" != "0" ]; then
  bash "$repo/scripts/check_builds.sh"
fi
