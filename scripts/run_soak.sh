#!/usr/bin/env bash
# A long camera-rate stream into the nodelet launched live
# (normal_fusion.launch live:=true num_inputs:=2), then bench_soak's table:
# output rate, drops, frame time and latency against the 33 ms budget,
# resident memory and its slope.
#
#   bash scripts/run_soak.sh [SECONDS] [bench_soak options]    (default 600)
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${NF_WS:-$repo/.build/ws}"
seconds="${1:-600}"
shift || true

bash "$repo/scripts/build.sh" >/dev/null
set +u
# shellcheck disable=SC1091
source "$ws/devel/setup.bash"
set -u
logs="$(mktemp -d /tmp/normal_fusion_soak.XXXXXX)"
port="$(python3 -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')"
export ROS_MASTER_URI="http://localhost:$port" ROS_HOSTNAME=localhost ROS_LOG_DIR="$logs"
core_pid="" launch_pid=""
cleanup() {
  for pid in $launch_pid $core_pid; do
    kill -INT "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
}
trap cleanup EXIT
roscore -p "$port" >"$logs/roscore.log" 2>&1 &
core_pid=$!
for _ in $(seq 1 60); do
  rosparam get /rosversion >/dev/null 2>&1 && break
  sleep 0.5
done
roslaunch normal_fusion normal_fusion.launch live:=true num_inputs:=2 \
  output:=log >"$logs/launch.log" 2>&1 &
launch_pid=$!
for _ in $(seq 1 60); do
  rosnode list 2>/dev/null | grep -q '^/normal_fusion$' && break
  sleep 0.5
done
echo "normal_fusion soak: $seconds s, logs in $logs"
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), load $(cut -d' ' -f1-3 /proc/loadavg)"
"$ws/devel/lib/normal_fusion/bench_soak" --duration "$seconds" "$@"
