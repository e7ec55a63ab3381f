#!/usr/bin/env bash
# The ROS demo: sets up and builds normal_fusion, starts its own ROS master on a
# free port, builds a bag from a real RGB-D sequence shipped by Debian (the
# ViSP castel sequence of visp-images-data: 30 frames of an Intel SR300) with
# two normal estimates per frame, plays it through the nodelet with roslaunch
# (launch/bag.launch) into a bag, runs the offline tool fuse_bag on the same
# bag, and writes pictures and a summary into the output folder.
# Without visp-images-data it runs on a synthetic sequence and says so.
#
# usage: scripts/run_demo.sh [OUTPUT_DIR] [--keep-bags] [--synthetic]
#   OUTPUT_DIR   default: output/ in the repository
#   --keep-bags  keep the input and output bags in OUTPUT_DIR/bags
#   --synthetic  use the synthetic sequence even when the ViSP data is there
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${NF_WS:-$repo/.build/ws}"
out="$repo/output"
keep_bags=0
source_args=()
for arg in "$@"; do
  case "$arg" in
    --keep-bags) keep_bags=1 ;;
    --synthetic) source_args=(--synthetic) ;;
    -h|--help) sed -n '2,15p' "$0"; exit 0 ;;
    *) out="$arg" ;;
  esac
done

echo "== normal_fusion demo: set-up and build"
bash "$repo/scripts/build.sh"
set +u
# shellcheck disable=SC1091
source "$ws/devel/setup.bash"
set -u
bin="$ws/devel/lib/normal_fusion"

mkdir -p "$out/logs"
out="$(cd "$out" && pwd)"
if [ "$keep_bags" -eq 1 ]; then
  bags="$out/bags"
  mkdir -p "$bags"
else
  bags="$(mktemp -d /tmp/normal_fusion_demo.XXXXXX)"
fi
rm -rf "$out/frames"

core_pid=""
cleanup() {
  if [ -n "$core_pid" ]; then
    kill -INT "$core_pid" 2>/dev/null || true
    wait "$core_pid" 2>/dev/null || true
  fi
  if [ "$keep_bags" -eq 0 ]; then rm -rf "$bags"; fi
}
trap cleanup EXIT

echo "== the input bag"
rm -f "$bags/ground_truth.bag"
"$bin/make_demo_bag" --output "$bags/input.bag" \
  --ground-truth "$bags/ground_truth.bag" ${source_args[@]+"${source_args[@]}"} |
  tee "$out/data_source.txt"

echo "== a ROS master on a free port"
port="$(python3 -c 'import socket; s = socket.socket(); s.bind(("", 0)); print(s.getsockname()[1])')"
export ROS_MASTER_URI="http://localhost:$port" ROS_HOSTNAME=localhost
export ROS_LOG_DIR="$out/logs"
roscore -p "$port" >"$out/logs/roscore.log" 2>&1 &
core_pid=$!
for _ in $(seq 1 60); do
  if rosparam get /rosversion >/dev/null 2>&1; then break; fi
  if ! kill -0 "$core_pid" 2>/dev/null; then
    echo "normal_fusion demo: roscore failed (log: $out/logs/roscore.log)" >&2
    exit 1
  fi
  sleep 0.5
done
rosparam get /rosversion >/dev/null 2>&1 || {
  echo "normal_fusion demo: no master on port $port after 30 s" >&2
  exit 1
}
echo "roscore (pid $core_pid) at $ROS_MASTER_URI"

echo "== the bag through the nodelet (roslaunch normal_fusion bag.launch)"
# 30 frames at 1/20 of their 30 Hz: one frame every 0.67 s, above the solve
# time of the 200-iteration budget, so that no frame is dropped.
roslaunch normal_fusion bag.launch input:="$bags/input.bag" \
  output:="$bags/fused.bag" num_inputs:=2 params:="$repo/config/demo.yaml" \
  rate:=0.05 output_log:=log >"$out/logs/roslaunch.log" 2>&1 || {
  tail -n 30 "$out/logs/roslaunch.log"
  echo "normal_fusion demo: roslaunch failed (log: $out/logs/roslaunch.log)" >&2
  exit 1
}

echo "== the same bag offline (fuse_bag)"
"$bin/fuse_bag" --input "$bags/input.bag" --output "$bags/fused_offline.bag" \
  --params "$repo/config/demo.yaml" | tee "$out/fuse_bag.txt"

echo "== pictures and summary"
report_args=(--input "$bags/input.bag" --fused "$bags/fused.bag"
  --offline "$bags/fused_offline.bag" --dir "$out")
if [ -f "$bags/ground_truth.bag" ]; then
  report_args+=(--ground-truth "$bags/ground_truth.bag"
    --title "normal_fusion ROS demo on a SYNTHETIC sequence (not the ViSP data)")
else
  report_args+=(--title "normal_fusion ROS demo: the ViSP castel RGB-D sequence (Intel SR300)")
fi
"$bin/bag_report" "${report_args[@]}"
{
  echo
  echo "## How this was made"
  echo
  echo '- data: '"$(cat "$out/data_source.txt")"
  if [ -f "$bags/ground_truth.bag" ]; then
    echo '- synthetic: a ray-cast room (320x240); both inputs come from a noisy depth map (the same recipes as below, no registration needed); exact normals give the accuracy table'
  fi
  echo '- normals_0: central differences of the raw depth (640x480), in the depth camera, rotated into the colour camera and registered into the colour image by forward projection with a z-buffer (depth_M_color.txt and both intrinsics); unobserved pixels are missing'
  echo '- normals_1: the depth median-pooled 4x4 and smoothed 3x3, then differentiated: 160x120, registered likewise; the nodelet upsamples it (bilinear) to the image'
  echo '- parameters: `config/demo.yaml` over the library defaults; played at 1/20 of real time through `launch/bag.launch`'
  echo '- offline run: `fuse_bag` output in `fuse_bag.txt`; logs in `logs/`'
  if [ "$keep_bags" -eq 0 ]; then
    echo '- the bags named above were temporary (run with --keep-bags to keep them in `bags/`)'
  fi
} >>"$out/summary.md"
echo "normal_fusion demo: done; see $out/summary.md and $out/frames/"
