#!/usr/bin/env bash
# Benchmarks of the haptic service (docs/BENCHMARKS.md, "Haptic service"):
#   1. 60 s at 5832 nodes with the stream on, then the same with it off;
#   2. 20 s at 1458, 5832 and 23328 nodes (1 kHz independent of mesh size).
# Reports go to out/bench_service/*.json; a summary table is printed.
# Usage: tools/bench_service.sh [seconds_long] [seconds_short]
set -euo pipefail
cd "$(dirname "$0")/.."
long=${1:-60}
short=${2:-20}
out=out/bench_service
mkdir -p "$out"
cargo build --release --quiet
bin=target/release/nvtmm
cfg() { # nodes stream -> config path
  local nodes=$1 stream=$2 dir="$out/cfg_${1}_${2}"
  mkdir -p "$dir"
  sed "s/^arch_nodes = .*/arch_nodes = $nodes/" rt-config/scenes/arch_service.toml > "$dir/scene.toml"
  sed -e "s#^scene = .*#scene = \"scene.toml\"#" \
      -e "s#^touchx = .*#touchx = \"$PWD/rt-config/touchx.toml\"#" \
      -e "s#^udp = .*#udp = \"$PWD/rt-config/udp_device.toml\"#" \
      -e "/^\[stream\]/,/^\[/ s/^enabled = .*/enabled = $stream/" \
      rt-config/nvtmm.toml > "$dir/nvtmm.toml"
  echo "$dir/nvtmm.toml"
}
run() { # name nodes stream seconds
  local c; c=$(cfg "$2" "$3")
  "$bin" run "$c" --seconds "$4" --quiet --report-json "$out/$1.json" > "$out/$1.txt"
}
run long_stream_on 5832 true "$long"
run long_stream_off 5832 false "$long"
for n in 1458 5832 23328; do run "short_$n" "$n" false "$short"; done
python3 - "$out" <<'PY'
import json, sys, os
out = sys.argv[1]
rows = ["long_stream_on", "long_stream_off", "short_1458", "short_5832", "short_23328"]
print("| run | nodes | ticks | s | misses (compute) | jitter p50/p99/p99.9/max µs | baseline p50/p99/p99.9/max µs | compute p50/p99/p99.9/max µs | pose→force p50/p99 µs | allocs | swaps | refresh p50 ms | stream frames |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
f = lambda p: "%.0f/%.0f/%.0f/%.0f" % (p["p50"], p["p99"], p["p999"], p["max"])
for r in rows:
    j = json.load(open(os.path.join(out, r + ".json")))
    print("| %s | %d | %d | %.1f | %d (%d) | %s | %s | %s | %.0f/%.0f | %d | %d | %.1f | %d |" % (
        r, j["nodes"], j["ticks"], j["seconds"], j["deadline_misses"], j["deadline_misses_compute"],
        f(j["period_jitter_us"]), f(j["baseline_jitter_us"]), f(j["tick_compute_us"]),
        j["pose_to_force_latency_us"]["p50"], j["pose_to_force_latency_us"]["p99"],
        j["allocations_after_start"], j["model_swaps"], j["background"]["refresh_ms"]["p50"], j["stream_frames"]))
a = json.load(open(os.path.join(out, "long_stream_on.json")))["tick_compute_us"]
b = json.load(open(os.path.join(out, "long_stream_off.json")))["tick_compute_us"]
print()
print("stream on / off, tick compute: p50 %.2f, p99 %.2f, p99.9 %.2f" % (a["p50"]/b["p50"], a["p99"]/b["p99"], a["p999"]/b["p999"]))
PY
