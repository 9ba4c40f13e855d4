#!/usr/bin/env bash
# Stage-1 time of two forms of the depth-normal prior, alternating in one sitting (BENCHMARKS.md):
#   bash scripts/bench_normal_prior.sh SCENE OUT [ROUNDS] [STAGE1_STEPS] [FORM_A FORM_B]
# Each round trains SCENE with --normal-prior-FORM_A and --normal-prior-FORM_B (default: per-gaussian,
# today's default, and blended; Session 26 compared normals-only and moves-depth) with 2 threads,
# stage 2 off and 200 autoencoder steps, and reads stage 1's seconds from run.json; the medians and
# their ratio are printed. OUT is replaced.
set -euo pipefail
scene=$1; out=$2; rounds=${3:-3}; steps=${4:-1500}; form_a=${5:-per-gaussian}; form_b=${6:-blended}
rm -rf "$out"; mkdir -p "$out"
for r in $(seq 1 "$rounds"); do
  for form in "$form_a" "$form_b"; do
    brfgs train "$scene" "$out/${form}_$r" --quiet --threads 2 --stage1-steps "$steps" --stage2-steps 0 \
      --schedule-ref-views 0 --ae-steps 200 --normal-prior-$form > /dev/null
  done
done
python - "$out" "$rounds" "$form_a" "$form_b" <<'PY'
import json, statistics, sys
out, rounds, forms = sys.argv[1], int(sys.argv[2]), sys.argv[3:5]
med = {}
for form in forms:
    t = [json.load(open(f"{out}/{form}_{r}/run.json"))["timings_s"]["stage1"] for r in range(1, rounds + 1)]
    med[form] = statistics.median(t)
    print(f"{form}: stage 1 {', '.join(f'{x:.1f}' for x in t)} s; median {med[form]:.1f} s")
print(f"ratio {forms[0]} / {forms[1]}: {med[forms[0]] / med[forms[1]]:.3f}")
PY
