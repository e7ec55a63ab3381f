#!/usr/bin/env bash
# Sets up (Debian packages) and builds normal_fusion in a catkin workspace.
# The workspace defaults to .build/ws inside the repository; NF_WS overrides it.
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${NF_WS:-$repo/.build/ws}"
jobs="${NF_JOBS:-$(nproc)}"

bash "$repo/scripts/setup.sh"
mkdir -p "$ws/src"
ln -sfn "$repo" "$ws/src/normal_fusion"
cd "$ws"
catkin_make -j"$jobs" -DCMAKE_BUILD_TYPE=Release \
  -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 \
  -DCATKIN_ENABLE_TESTING=ON "$@" >"$ws/build.log" 2>&1 || {
  tail -n 60 "$ws/build.log"
  echo "normal_fusion: build failed (full log: $ws/build.log)" >&2
  exit 1
}
grep -E "warning:" "$ws/build.log" | sort -u | head -n 20 || true
echo "normal_fusion: built in $ws"
