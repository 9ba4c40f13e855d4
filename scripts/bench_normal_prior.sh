#!/usr/bin/env bash
# Stage-1 time of the depth-normal prior's two forms, alternating in one sitting (BENCHMARKS.md):
#   bash scripts/bench_normal_prior.sh SCENE OUT [ROUNDS] [STAGE1_STEPS]
# Each round trains SCENE with --normal-prior-normals-only (the default) and --normal-prior-moves-depth
# (2 threads, stage 2 off, 200 autoencoder steps) and reads stage 1's seconds from run.json; the medians
# and their ratio are printed. OUT is replaced.
set -euo pipefail
scene=$1; out=$2; rounds=${3:-3}; steps=${4:-1500}
rm -rf "$out"; mkdir -p "$out"
for r in $(seq 1 "$rounds"); do
  for form in normals-only moves-depth; do
    brfgs train "$scene" "$out/${form}_$r" --quiet --threads 2 --stage1-steps "$steps" --stage2-steps 0 \
      --schedule-ref-views 0 --ae-steps 200 --normal-prior-$form > /dev/null
  done
done
python - "$out" "$rounds" <<'PY'
import json, statistics, sys
out, rounds = sys.argv[1], int(sys.argv[2])
med = {}
for form in ("normals-only", "moves-depth"):
    t = [json.load(open(f"{out}/{form}_{r}/run.json"))["timings_s"]["stage1"] for r in range(1, rounds + 1)]
    med[form] = statistics.median(t)
    print(f"{form}: stage 1 {', '.join(f'{x:.1f}' for x in t)} s; median {med[form]:.1f} s")
print(f"ratio normals-only / moves-depth: {med['normals-only'] / med['moves-depth']:.3f}")
PY
