#!/usr/bin/env bash
# The ROS demo: sets up and builds normal_fusion, starts its own ROS master on a
# free port, builds a driver's bag from a real RGB-D sequence shipped by Debian
# (the ViSP castel sequence of visp-images-data: 30 frames of an Intel SR300;
# colour image, depth, both camera_infos, tf), plays it with roslaunch
# (launch/demo.launch) through two DepthToNormalsNodelets (the depth's normals
# at two scales, registered into the colour camera) and the fusion nodelet in
# one manager into a bag, runs the offline tool fuse_bag on the recorded
# normals, and writes pictures and a summary into the output folder.
# Without visp-images-data it runs on a synthetic sequence and says so.
#
# usage: scripts/run_demo.sh [OUTPUT_DIR] [--keep-bags] [--synthetic]
#   OUTPUT_DIR   default: output/ in the repository
#   --keep-bags  keep the input and output bags in OUTPUT_DIR/bags
#   --synthetic  use the synthetic sequence even when the ViSP data is there
# The two scales (method and plane_fit window radius of normals_0 and
# normals_1) can be changed with NF_DEMO_METHOD_0, NF_DEMO_RADIUS_0,
# NF_DEMO_METHOD_1 and NF_DEMO_RADIUS_1.
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${NF_WS:-$repo/.build/ws}"
out="$repo/output"
keep_bags=0
source_args=()
# The depth normals' two scales (docs/demo.md says why these).
method_0="${NF_DEMO_METHOD_0:-central_difference}"
radius_0="${NF_DEMO_RADIUS_0:-1}"
method_1="${NF_DEMO_METHOD_1:-plane_fit}"
radius_1="${NF_DEMO_RADIUS_1:-2}"
for arg in "$@"; do
  case "$arg" in
    --keep-bags) keep_bags=1 ;;
    --synthetic) source_args=(--synthetic) ;;
    -h|--help) sed -n '2,19p' "$0"; exit 0 ;;
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

echo "== the driver's bag"
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

echo "== the bag through the depth nodelets and the fusion (roslaunch normal_fusion demo.launch)"
# 30 frames at 1/40 of their 30 Hz: one frame every 1.3 s, about twice the
# time of the depth normals and the 200-iteration solve on two busy cores, so
# that no frame is dropped.
roslaunch normal_fusion demo.launch input:="$bags/input.bag" \
  output:="$bags/fused.bag" params:="$repo/config/demo.yaml" rate:=0.025 \
  method_0:="$method_0" window_radius_0:="$radius_0" \
  method_1:="$method_1" window_radius_1:="$radius_1" \
  output_log:=log >"$out/logs/roslaunch.log" 2>&1 || {
  tail -n 30 "$out/logs/roslaunch.log"
  echo "normal_fusion demo: roslaunch failed (log: $out/logs/roslaunch.log)" >&2
  exit 1
}

# What the depth nodelets ran with, as they wrote it to the parameter server.
describe_depth_node() {
  local node="$1" method radius
  method="$(rosparam get "/$node/method")"
  radius="$(rosparam get "/$node/window_radius")"
  if [ "$method" = plane_fit ]; then
    echo "plane_fit, window_radius $radius ($((2 * radius + 1))x$((2 * radius + 1)) window)"
  else
    echo "$method"
  fi
}
registered="aligned to the colour image"
if [ "$(rosparam get /depth_to_normals/register_to_rgb)" = true ]; then
  registered="registered into the colour camera (register_to_rgb, $(rosparam get /depth_to_normals/registration_splat) splat; the transform from the bag's /tf_static)"
fi
normals_source="normals computed from depth by normal_fusion/DepthToNormalsNodelet at two scales (normals_0: $(describe_depth_node depth_to_normals); normals_1: $(describe_depth_node depth_to_normals_1); noise_coefficient $(rosparam get /depth_to_normals/noise_coefficient) /m), $registered, in one nodelet manager with the fusion nodelet"

normals_topics=(--image /camera/color/image_raw
  --camera-info /camera/color/camera_info
  --normals-0 /depth_to_normals/normals --normals-1 /depth_to_normals_1/normals)
echo "== the recorded normals offline (fuse_bag)"
"$bin/fuse_bag" --input "$bags/fused.bag" --output "$bags/fused_offline.bag" \
  --params "$repo/config/demo.yaml" "${normals_topics[@]}" |
  tee "$out/fuse_bag.txt"

echo "== pictures and summary"
report_args=(--input "$bags/fused.bag" --fused "$bags/fused.bag"
  --offline "$bags/fused_offline.bag" --dir "$out"
  --image /camera/color/image_raw --normals-0 /depth_to_normals/normals
  --normals-1 /depth_to_normals_1/normals --played "$bags/input.bag"
  --normals-source "$normals_source" --run "demo.launch")
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
  echo '- the driver'"'"'s bag (`make_demo_bag`) holds only what a camera driver records: /camera/color/image_raw and /camera/color/camera_info, /camera/depth/image_rect_raw (16UC1 mm) and /camera/depth/camera_info, /tf_static (depth to colour optical frame) and, where the sequence has camera poses, /tf'
  if [ -f "$bags/ground_truth.bag" ]; then
    echo '- synthetic: a ray-cast room (320x240), the depth rendered from a depth camera 25 mm beside the colour camera with a depth camera'"'"'s noise; exact normals of the colour camera give the accuracy table'
  fi
  echo "- $normals_source (\`launch/demo.launch\` over \`launch/rgbd.launch\`)"
  echo '- parameters: `config/demo.yaml` over the library defaults; played at 1/40 of real time; the recorded bag holds the colour image, both normal maps, the fused map and the statistics'
  echo '- offline run: `fuse_bag` on the recorded image and normal maps, output in `fuse_bag.txt`; logs in `logs/`'
  if [ "$keep_bags" -eq 0 ]; then
    echo '- the bags named above were temporary (run with --keep-bags to keep them in `bags/`)'
  fi
} >>"$out/summary.md"
echo "normal_fusion demo: done; see $out/summary.md and $out/frames/"
