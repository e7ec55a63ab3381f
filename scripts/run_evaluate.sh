#!/usr/bin/env bash
# The evaluation: sets up, builds, and runs `evaluate` on the synthetic scenes
# (prints the accuracy table and writes it with a plot into results/).
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${NF_WS:-$repo/.build/ws}"

bash "$repo/scripts/build.sh"
out="${1:-$repo/results}"
mkdir -p "$out"
"$ws/devel/lib/normal_fusion/evaluate" --output-dir "$out" "${@:2}"
