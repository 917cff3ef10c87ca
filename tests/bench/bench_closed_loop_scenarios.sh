#!/usr/bin/env bash
# Undisturbed closed loops of every shipped `all` scenario: `plan --terrain S --constraints all`,
# then `simulate --replan-every 0.1 --horizon 1` (the simulation's deterministic re-plan budget,
# --replan-iterations, unless given in EXTRA), one row per scene: the verdict, re-plans, failed
# steps (refused, or whose solve failed: the session's plan kept), fallbacks, own solutions and the
# iterations per re-plan (median, max).
#   tests/bench/bench_closed_loop_scenarios.sh [build/terrastride] [SCENES=flat,...] [EXTRA simulate flags...]
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
bin=${1:-$root/build/terrastride}
scenes=${2:-flat,pallet_10,pallet_15,stairs,eur_pallet,gap}
shift $(( $# < 2 ? $# : 2 ))
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
# OpenBLAS picks its kernels by the CPU, and the iterates, so the counts below, follow
# (tests/bench/blas_kernel.hpp): pinned to Haswell's where the CPU has AVX2, unless the caller set it.
if [[ -z ${OPENBLAS_CORETYPE:-} ]] && grep -q '^flags.* avx2' /proc/cpuinfo; then
  export OPENBLAS_CORETYPE=Haswell
fi
uptime
echo "BLAS kernel: ${OPENBLAS_CORETYPE:-chosen by OpenBLAS}"
printf '%-11s %-8s %7s %7s %9s %5s %11s  %s\n' scene verdict replans failed fallbacks own "iters p50/max" "failed steps (t: reason)"
for s in ${scenes//,/ }; do
  "$bin" plan --terrain "$s" --constraints all --out "$scratch/$s.json" >/dev/null
  code=0
  "$bin" simulate "$scratch/$s.json" --terrain "$s" --replan-every 0.1 --horizon 1 --json "$@" \
    >"$scratch/$s.sim.json" || code=$?
  python3 - "$s" "$scratch/$s.sim.json" "$code" <<'PY'
import json, sys
name, path, code = sys.argv[1], sys.argv[2], sys.argv[3]
r = json.load(open(path))
c = r.get("closed_loop", {})
steps = c.get("steps", [])
own = sum(1 for s in steps if s.get("fallback") is None)
# A failed step: the re-planner refused it (replan_failures) or its solve failed and the step
# answered with the session's plan (fallback "solve_failed").
failed = [f"{t:.1f}" for t in c.get("failure_times", [])]
failed += [f"{s['t']:.1f}" for s in steps if s.get("fallback") == "solve_failed"]
print(f"{name:<11} {r.get('verdict','?'):<8} {c.get('replans',0):7d} {len(failed):7d} "
      f"{c.get('fallbacks',0):9d} {own:5d} {c.get('planner_iterations_median',0):>5}/{c.get('planner_iterations_max',0):<5} "
      f" {' '.join(failed)} {c.get('first_failure','') or ''} (exit {code})")
PY
done
