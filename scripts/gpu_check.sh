#!/usr/bin/env bash
# scripts/gpu_check.sh OUT: the CUDA path on a machine with an NVIDIA GPU, in one sitting.
#   1. gsplat's kernels build (JIT, first use) and render one frame;
#   2. the cuda tests: gsplat against the torch reference (outputs, gradients, AbsGS), a model kept
#      on the CPU, and training + rendering with --backend cuda against the cpu backend;
#   3. rasterizer frame times, cpu (numba, all cores) and cuda in alternating rounds of one run, and
#      cuda alone at 1886² with 1M Gaussians;
#   4. a 512 × 384 training on each backend (same seed and steps): phase times and scores;
#   5. one 1886² × 164-band view (`brfgs bench view`) with each backend.
# Needs brfgs with the cuda extra importable (`pip install -e ".[cuda]"`); each step's log goes to
# OUT/<step>.log and its JSON beside it; a step that fails is reported and the next one runs.
# GPU_CHECK_DEADLINE (epoch seconds): a step that would start with under 20 s left is skipped and each
# step's limit is cut to what is left (to fit a lent machine's call); GPU_CHECK_SKIP_VIEW=1 leaves
# out step 5. BENCHMARKS.md ("GPU") records the results and the command.
set -uo pipefail
out=${1:?usage: scripts/gpu_check.sh OUT}
mkdir -p "$out"
here=$(cd "$(dirname "$0")/.." && pwd)
export PYTHONUNBUFFERED=1 TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0} MAX_JOBS=${MAX_JOBS:-$(nproc)}
PY=${PYTHON:-python3}
work=${GPU_CHECK_WORK:-$(mktemp -d)}
cd "$here"

step() {  # step NAME SECONDS CMD...: run with a time limit, log to OUT/NAME.log, print its tail
  local name=$1 limit=$2 t0 rc left
  shift 2
  if [ -n "${GPU_CHECK_DEADLINE:-}" ]; then
    left=$(( GPU_CHECK_DEADLINE - $(date +%s) ))
    if (( left < 20 )); then echo "== $name: skipped, $left s left before GPU_CHECK_DEADLINE"; return 124; fi
    (( limit > left )) && limit=$left
  fi
  echo "== $name (limit $limit s): $*"
  t0=$(date +%s)
  timeout "$limit" "$@" > "$out/$name.log" 2>&1
  rc=$?
  echo "== $name: rc=$rc in $(( $(date +%s) - t0 )) s"
  tail -n "${TAIL:-15}" "$out/$name.log"
  return $rc
}

{ nvidia-smi -L; nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv; nproc; date -u
  lscpu | grep -i 'model name'
  "$PY" -c "import torch, numba; print('torch', torch.__version__, 'cuda', torch.version.cuda, 'numba', numba.__version__)"
} > "$out/machine.txt" 2>&1
cat "$out/machine.txt"

step build 420 "$PY" - <<'EOF' || exit 1
import time
import torch
t0 = time.perf_counter()
import gsplat  # noqa: F401
from brfgs.render import rasterize
from brfgs.render.scenes import random_scene
sc = random_scene(200, 32, 24, 3, seed=0)
sc = {k: (v.cuda() if torch.is_tensor(v) else v) for k, v in sc.items()}
out = rasterize(sc["means"], sc["quats"], sc["scales"], sc["opacities"], sc["features"], sc["viewmat"], sc["K"],
                32, 24, backend="cuda")
torch.cuda.synchronize()
print(f"gsplat {gsplat.__version__}: built and rendered in {time.perf_counter() - t0:.1f} s; "
      f"alpha max {out.alpha.max().item():.3f}")
EOF

step tests 420 "$PY" -m pytest -q -p no:cacheprovider -rs "$here/tests/test_render_rasterize.py" \
  "$here/tests/test_render_absgrad.py" "$here/tests/test_train_pipeline.py" -k "cuda"

step render 300 "$PY" -m brfgs bench render --backends cpu,cuda --sizes 256,1024 --gaussians 200000 \
  --channels 16,164 --repeats 3 --json "$out/render_cpu_cuda.json"
step render1886 200 "$PY" -m brfgs bench render --backends cuda --sizes 1886 --gaussians 1000000 \
  --channels 16,164 --repeats 5 --json "$out/render_1886.json"

"$PY" - "$work/plane" <<'EOF'
import sys
sys.path.insert(0, "tests")
from pathlib import Path
from test_train_scene import make_plane_scene
make_plane_scene(Path(sys.argv[1]), w=512, h=384, n_bands=16)
EOF
for be in cuda cpu; do
  step "train_$be" 300 "$PY" -m brfgs train "$work/plane" "$work/run_$be" --preset fast --backend "$be" \
    --stage1-steps 600 --stage2-steps 400 --ae-steps 500 --seed 0
  cp "$work/run_$be/run.json" "$out/train_${be}_run.json" 2>/dev/null
  cp "$work/run_$be/metrics.json" "$out/train_${be}_metrics.json" 2>/dev/null
done

[ "${GPU_CHECK_SKIP_VIEW:-0}" = 1 ] && exit 0
for be in cuda cpu; do
  step "view_$be" 200 "$PY" -m brfgs bench view --size 1886 --gaussians 1000000 --repeats 2 --backend "$be" \
    --json "$out/view_1886_$be.json"
done

echo "== done $(date -u)"
