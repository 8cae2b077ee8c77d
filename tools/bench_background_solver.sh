#!/usr/bin/env bash
# The background full solve's linear solver under a changing load: 100 steps
# of 10 ms (the service's background step) of the 5832-node arch with the
# service scene's material, Prony term and supports, and a 0.12 N force at
# the arch top varying as a 2 Hz sine. Prints ms/step and median CG
# iterations per solver. Usage: [SOLVERS="a b"] tools/bench_background_solver.sh [NODES]
set -euo pipefail
nodes="${1:-5832}"
cd "$(dirname "$0")/.."
cargo build --release --quiet
bin=target/release/nvtmm
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
declare -A solvers=(
  [cg_block_ic0]='kind = "cg", precond = "block_ic0", tol = 1e-6, max_iter = 500'
  [cholesky]='kind = "cholesky"'
  [cholesky_pcg_k3]='kind = "cholesky_pcg", tol = 1e-6, max_iter = 15, refactor_every = 3'
  [cholesky_pcg32_k3]='kind = "cholesky_pcg", tol = 1e-6, max_iter = 15, refactor_every = 3, factor_f32 = true'
  [cholesky_pcg_k8]='kind = "cholesky_pcg", tol = 1e-6, max_iter = 15, refactor_every = 8'
  [cholesky_pcg_lagged]='kind = "cholesky_pcg", tol = 1e-6, max_iter = 15, refactor_every = 100000'
)
echo "nodes=$nodes $(date -u +%FT%TZ) $(uptime | sed 's/.*load/load/')"
for name in ${SOLVERS:-cg_block_ic0 cholesky cholesky_pcg_k3 cholesky_pcg32_k3 cholesky_pcg_k8 cholesky_pcg_lagged}; do
  cat > "$dir/$name.toml" <<TOML
model = "nvtmm"
duration = $(python3 -c "print(100 * ${DT:-1e-2})")
[mesh]
arch_nodes = $nodes
[material]
law = "stvk"
youngs_pa = 65e3
poisson = 0.45
density = 1050.0
[[prony]]
alpha = 0.5
tau = 0.58
[fixed]
sets = ["inlet", "outlet_descending"]
[[load]]
near = [0.0065, -0.031, 0.177]
force_n = [0.0, 0.0, -0.12]
profile = { kind = "sine", freq_hz = 2.0, phase = 0.0 }
[integrator]
dt = ${DT:-1e-2}
rayleigh_alpha = 0.0
rayleigh_beta = 1e-3
newton = { max_iters = 1 }
linear = { ${solvers[$name]} }
[output]
vtu_every = 0
csv_every = 0
TOML
  "$bin" simulate "$dir/$name.toml" --out "$dir/out_$name" --quiet >/dev/null
  python3 - "$dir/out_$name/summary.json" "$name" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
print(f"{sys.argv[2]:22s} ms/step {d['ms_per_step']:7.1f}  cg_iters_median {d['cg_iters_median']:4d}  max_displacement_m {d['max_displacement_m']:.4e}")
PY
done
