#!/usr/bin/env bash
# Mesh benchmarks for docs/BENCHMARKS.md: arch sizes and quality at the
# paper's three sizes (or the sizes given), generation time, and write/read
# time per format at 23328 nodes. Usage: tools/bench_mesh.sh [NODES...]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q
bin=./target/release/nvtmm
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
now() { date +%s.%N; }
dt() { python3 -c "print(f'{$2 - $1:.3f}')"; }
sizes=("$@"); [ ${#sizes[@]} -gt 0 ] || sizes=(1458 5832 23328)
echo "| --nodes | nodes | tets | surface tris | min dihedral (°) | max aspect | inverted | generate + write .vtu (s) |"
echo "|---|---|---|---|---|---|---|---|"
for n in "${sizes[@]}"; do
  t0=$(now); $bin mesh arch --nodes "$n" --out "$tmp/a$n.vtu" >/dev/null; t1=$(now)
  $bin mesh info "$tmp/a$n.vtu" --json | python3 -c "
import json,sys; d=json.load(sys.stdin)
print(f\"| $n | {d['nodes']} | {d['tets']} | {d['surface_triangles']} | {d['min_dihedral_deg']:.1f} | {d['max_aspect_ratio']:.2f} | {d['inverted']} | $(dt $t0 $t1) |\")"
done
echo
echo "| format (23328 nodes) | files (MB) | generate + write (s) | read + topology + quality (s) |"
echo "|---|---|---|---|"
for ext in msh vtk vtu node; do
  t0=$(now); $bin mesh arch --nodes 23328 --out "$tmp/b.$ext" >/dev/null; t1=$(now)
  size=$(du -cm "$tmp"/b.* | tail -1 | cut -f1)
  t2=$(now); $bin mesh info "$tmp/b.$ext" >/dev/null; t3=$(now)
  echo "| .$ext | $size | $(dt $t0 $t1) | $(dt $t2 $t3) |"
  rm -f "$tmp"/b.*
done
