#!/usr/bin/env bash
# Builds normal_fusion and runs every benchmark, printing all figures in one
# run: throughput and the paper's workload (Google Benchmark), time to
# solution, memory, streaming. Takes a few minutes; run it on a quiet machine.
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ws="${NF_WS:-$repo/.build/ws}"
bash "$repo/scripts/build.sh" >/dev/null
bin="$ws/devel/lib/normal_fusion"
echo "# machine: $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores, $(uname -r)"
echo "# load average at start: $(cut -d' ' -f1-3 /proc/loadavg)"
"$bin/bench_solver" --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
echo
"$bin/bench_time_to_solution"
echo
"$bin/bench_memory"
echo
"$bin/bench_streaming" --frames "${NF_STREAM_FRAMES:-10}"
