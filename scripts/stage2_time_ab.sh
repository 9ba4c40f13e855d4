#!/usr/bin/env bash
# Stage 2's time with this checkout against another commit's, alternating in one run (BENCHMARKS.md).
#
#   bash scripts/stage2_time_ab.sh REF SCENE STAGE1_CKPT [ROUNDS] [STAGE2_STEPS] [THREADS]
#
# REF: a commit (e.g. HEAD~1); SCENE: a scene folder; STAGE1_CKPT: a run's checkpoints/stage1.safetensors
# on that scene. Both code versions train stage 2 from the same stage 1 (`brfgs train --from-stage1`,
# no evaluation), one after the other, ROUNDS times (default 5) after one warm-up each (numba compiles
# the other commit's kernels once); STAGE2_STEPS (default 40, scaled by the number of training views
# as any run's) and THREADS (default 2). Prints each round's stage-2 seconds from run.json, the
# medians, their ratio (this checkout / REF) and whether the two final models are bitwise identical.
set -euo pipefail
REF=$1; SCENE=$2; CKPT=$3; ROUNDS=${4:-5}; STEPS=${5:-40}; THREADS=${6:-2}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
WORK=$(mktemp -d /tmp/stage2_ab.XXXXXX)
git -C "$ROOT" worktree add -q --detach "$WORK/ref" "$REF"
trap 'git -C "$ROOT" worktree remove --force "$WORK/ref"; rm -rf "$WORK"' EXIT

run() {  # run NAME SRC: one stage-2 run with the package at SRC; prints its stage-2 seconds
  rm -rf "$WORK/$1"
  PYTHONPATH=$2 python -m brfgs train "$SCENE" "$WORK/$1" --from-stage1 "$CKPT" --stage2-steps "$STEPS" \
    --threads "$THREADS" --quiet --no-evaluate > "$WORK/$1.log" 2>&1
  python -c "import json,sys; print(json.load(open(sys.argv[1]))['timings_s']['stage2'])" "$WORK/$1/run.json"
}

run run_ref "$WORK/ref/src" > /dev/null  # warm-up: numba caches of both trees
run run_new "$ROOT/src" > /dev/null
: > "$WORK/times"
for r in $(seq 1 "$ROUNDS"); do
  a=$(run run_ref "$WORK/ref/src"); b=$(run run_new "$ROOT/src")
  echo "round $r: $REF ${a} s, this checkout ${b} s"
  echo "$a $b" >> "$WORK/times"
done
python - "$WORK" <<'EOF'
import statistics, sys
from safetensors.torch import load_file
work = sys.argv[1]
rows = [tuple(map(float, line.split())) for line in open(f"{work}/times")]
ref, new = statistics.median(r[0] for r in rows), statistics.median(r[1] for r in rows)
print(f"median stage 2: REF {ref:.1f} s, this checkout {new:.1f} s, ratio {new / ref:.3f}")
a, b = load_file(f"{work}/run_ref/model.safetensors"), load_file(f"{work}/run_new/model.safetensors")
same = a.keys() == b.keys() and all(bool((a[k] == b[k]).all()) for k in a)
print("final models bitwise identical:", same)
EOF
