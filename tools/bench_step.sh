#!/usr/bin/env bash
# The full implicit step table of docs/BENCHMARKS.md: `nvtmm bench step` for
# MSM, TMM, NVTMM and FEM (StVK) on the 1458 / 5832 / 23328-node arch under
# the standard load, with four solver settings each:
#   exact    --linear cholesky         --stiffness-every 1   (sparse Cholesky every step)
#   pcg3     --linear cholesky-pcg:3   --stiffness-every 1   (exact; CG on a factor refreshed every 3 solves)
#   pcg32_3  --linear cholesky-pcg32:3 --stiffness-every 1   (exact; the same with the factor in f32)
#   lag10    --linear cholesky         --stiffness-every 10  (approximate: lagged tangent)
# Prints one JSON line per run, then a Markdown table.
# Usage: tools/bench_step.sh [SIZES...]   (default: 1458 5832 23328)
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
bin=target/release/nvtmm
sizes=("$@")
[ ${#sizes[@]} -eq 0 ] && sizes=(1458 5832 23328)
out=$(mktemp)
trap 'rm -f "$out"' EXIT
echo "# $(date -u +%FT%TZ) $(nproc) cores, $(uptime | sed 's/.*load/load/'), commit $(git rev-parse --short HEAD)"
for n in "${sizes[@]}"; do
  case $n in
    1458) steps=40 ;;
    5832) steps=20 ;;
    *) steps=10 ;;
  esac
  for model in msm tmm nvtmm fem; do
    for setting in exact pcg3 pcg32_3 lag10; do
      case $setting in
        exact) args=(--linear cholesky --stiffness-every 1) ;;
        pcg3) args=(--linear cholesky-pcg:3 --stiffness-every 1) ;;
        pcg32_3) args=(--linear cholesky-pcg32:3 --stiffness-every 1) ;;
        lag10) args=(--linear cholesky --stiffness-every 10) ;;
      esac
      if line=$("$bin" bench step --model "$model" --nodes "$n" --steps "$steps" "${args[@]}" --json 2>&1 | tr -d '\n '); then
        echo "{\"setting\":\"$setting\",${line#\{}" | tee -a "$out"
      else
        echo "{\"setting\":\"$setting\",\"model\":\"$model\",\"nodes\":$n,\"error\":\"$(echo "$line" | tr -d '"' | tail -c 200)\"}" | tee -a "$out"
      fi
    done
  done
done
python3 - "$out" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
print()
print("| nodes | model | setting | median ms/step | mean ms/step | steps/s (1000/mean) | max ms | CG iters (median) | loaded-node displacement (mm) |")
print("|---:|---|---|---:|---:|---:|---:|---:|---:|")
for r in rows:
    if "error" in r:
        print(f"| {r['nodes']} | {r['model']} | {r['setting']} | failed: {r['error']} | | | | | |")
        continue
    print(f"| {r['nodes']} | {r['model']} | {r['setting']} | {r['ms_per_step']:.2f} | {r['mean_ms_per_step']:.2f} | "
          f"{1000 / r['mean_ms_per_step']:.0f} | {r['max_ms_per_step']:.1f} | {r['cg_iters']} | {1e3 * r['load_node_displacement_m']:.3f} |")
print()
print("| nodes | setting | FEM / NVTMM median step time | (mean) |")
print("|---:|---|---:|---:|")
by = {(r['nodes'], r['model'], r['setting']): r for r in rows if "error" not in r}
for (n, m, s), r in by.items():
    if m == "nvtmm" and (n, "fem", s) in by:
        f = by[(n, "fem", s)]
        print(f"| {n} | {s} | {f['ms_per_step'] / r['ms_per_step']:.2f} | {f['mean_ms_per_step'] / r['mean_ms_per_step']:.2f} |")
PY
