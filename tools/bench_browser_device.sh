#!/usr/bin/env bash
# The loop's tick with the browser as the device, side by side with the
# simulated Touch X (docs/BENCHMARKS.md, "Browser as the device").
#
# Both runs are the guidewire scene of rt-config/drive.toml with the wire
# held still where it starts (20 mm in):
#   browser: `nvtmm view --drive` with the page open in headless Chromium
#            (idle: it sends its pose every 40 ms, the view server turns it
#            into 1 kHz UDP poses), the service on the UDP bridge;
#   sim:     the same file on the simulated Touch X, the hub held by a
#            script at the same insertion.
# The runs alternate (browser, sim, browser, sim, ...) so that a change in
# the machine's load falls on both. Reports go to out/bench_browser_device/.
# Usage: tools/bench_browser_device.sh [seconds] [rounds]
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-20}
rounds=${2:-2}
out=out/bench_browser_device
mkdir -p "$out"
chromium=${NVTMM_CHROMIUM:-$(command -v chromium || command -v chromium-browser || command -v google-chrome || true)}
if [ -z "$chromium" ]; then
  echo "needs Chromium (set NVTMM_CHROMIUM or put chromium on PATH)" >&2
  exit 2
fi
cargo build --release --quiet
bin=$PWD/target/release/nvtmm
rt=$PWD/rt-config
http=127.0.0.1:18480
stream=127.0.0.1:17878

# Ports of their own, so that a viewer or a service already running on the
# shipped ones is not disturbed.
sed -e 's#^bind = .*#bind = "127.0.0.1:47110"#' "$rt/udp_browser.toml" > "$out/udp_browser.toml"
common=(-e "s#^scene = .*#scene = \"$rt/scenes/guidewire_arch.toml\"#"
        -e "s#^touchx = .*#touchx = \"$rt/touchx.toml\"#"
        -e "s#^target = .*#target = \"$stream\"#"
        -e "s#^hud_target = .*#hud_target = \"127.0.0.1:17879\"#"
        -e "s#^session_dir = .*#session_dir = \"$PWD/$out/sessions\"#")
sed "${common[@]}" -e "s#^udp = .*#udp = \"$PWD/$out/udp_browser.toml\"#" \
  "$rt/drive.toml" > "$out/browser.toml"
# The simulated Touch X, the hub held by a script where the idle page
# leaves it (`[guidewire] inserted_m`).
sed "${common[@]}" -e 's#^backend = .*#backend = "touchx-sim"#' \
  -e "s#^udp = .*#udp = \"$rt/udp_device.toml\"#" \
  -e "/^\[guidewire\]/a script = [[0.0, 0.02, 0.0], [$seconds.0, 0.02, 0.0]]" \
  "$rt/drive.toml" > "$out/sim.toml"

pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap cleanup EXIT

browser_run() { # name
  "$bin" view --listen "$http" --stream "$stream" --drive "$out/browser.toml" > "$out/view.log" 2>&1 &
  pids+=($!)
  for _ in $(seq 100); do curl -sf "http://$http/drive/info" > /dev/null && break; sleep 0.2; done
  "$chromium" --headless --no-sandbox --disable-gpu --no-first-run --window-size=900,650 \
    --disable-background-timer-throttling --disable-renderer-backgrounding --disable-backgrounding-occluded-windows \
    --user-data-dir="$out/profile" "http://$http/" > /dev/null 2>&1 &
  pids+=($!)
  sleep 5 # the page loads and opens its drive socket before the service starts
  "$bin" run "$out/browser.toml" --seconds "$seconds" --quiet --report-json "$out/$1.json" > "$out/$1.txt"
  cleanup
  pids=()
}
sim_run() { # name
  "$bin" run "$out/sim.toml" --seconds "$seconds" --quiet --report-json "$out/$1.json" > "$out/$1.txt"
}
names=()
for r in $(seq "$rounds"); do
  browser_run "browser_$r"; names+=("browser_$r")
  sim_run "sim_$r"; names+=("sim_$r")
done

python3 - "$out" "${names[@]}" <<'PY'
import json, sys, os
out, names = sys.argv[1], sys.argv[2:]
print("| run | ticks | device silent ticks | watchdog ticks | compute p50/p99/p99.9/max µs | jitter p99/max µs | wire inserted mm |")
print("|---|---:|---:|---:|---|---|---:|")
f = lambda p: "%.0f/%.0f/%.0f/%.0f" % (p["p50"], p["p99"], p["p999"], p["max"])
for n in names:
    j = json.load(open(os.path.join(out, n + ".json")))
    w = next((i for i in j.get("instruments", []) if i.get("kind") == "guidewire"), {})
    print("| %s | %d | %s | %s | %s | %.0f/%.0f | %.1f |" % (
        n, j["ticks"], j["watchdog"]["device_silent_ticks"], j["watchdog"]["watchdog_ticks"],
        f(j["tick_compute_us"]), j["period_jitter_us"]["p99"], j["period_jitter_us"]["max"],
        1e3 * w.get("keys", {}).get("inserted_m", float("nan"))))
PY
