#!/usr/bin/env bash
# Regression check between two checkouts of brfgs: every model variant trained on a tiny plane scene
# (BRF-GS, SH-3 from its stage 1, neural, CIR, joint, the compiled CPU backend), then evaluated, rendered,
# analysed and exported; the model tensors (model file and checkpoints), metrics and training logs of the
# two checkouts compared bit for bit (timings and paths left out). Both checkouts train here, in this
# run, on this machine: bit for bit holds between two models made on the same CPU and software, never
# against numbers stored from another machine (another CPU rounds float32 reductions differently;
# docs/reliability.md, "Determinism").
#
#   bash scripts/regression.sh OLD_CHECKOUT [NEW_CHECKOUT] [OUT]
#
# e.g. `git worktree add /tmp/old v0.1.0 && bash scripts/regression.sh /tmp/old`. Exit 0 when every
# tensor and metric is identical, 1 otherwise. About 3 minutes per checkout on 2 cores.
set -euo pipefail
old=$(cd "${1:?usage: bash scripts/regression.sh OLD_CHECKOUT [NEW_CHECKOUT] [OUT]}" && pwd)
new=$(cd "${2:-$(dirname "$0")/..}" && pwd)
out=${3:-$(mktemp -d -t brfgs-regression-XXXX)}
PY=${PYTHON:-python3}
mkdir -p "$out"

runs() {  # runs CHECKOUT DIR: the tiny runs of one checkout
  local src=$1 dir=$2
  rm -rf "$dir"; mkdir -p "$dir"
  export PYTHONPATH=$src/src:$src/tests
  "$PY" -c "from pathlib import Path; from test_train_scene import make_plane_scene; make_plane_scene(Path('$dir/scene'), w=48, h=32, n_bands=16)"
  local b="$PY -m brfgs" t="--preset tiny --quiet --threads 1"
  $b train "$dir/scene" "$dir/brf" $t
  $b train "$dir/scene" "$dir/sh" $t --variant sh --from-stage1 "$dir/brf/checkpoints/stage1.safetensors"
  $b train "$dir/scene" "$dir/neural" $t --variant neural
  $b train "$dir/scene" "$dir/cir" $t --variant cir
  $b train "$dir/scene" "$dir/joint" $t --joint
  $b train "$dir/scene" "$dir/brfcpu" $t --backend cpu --stage1-steps 40
  $b evaluate "$dir/brf" --quiet --backend torch --split train
  $b render "$dir/brf" --view-zenith 20 --view-azimuth 45 --out "$dir/render_brf" --quiet --backend torch
  $b brf "$dir/brf" --roi "box:view_00:0,0,16,12" --out "$dir/brf_brf" --quiet --backend torch
  $b products "$dir/brf" --out "$dir/prod_brf" --quiet --backend torch
  $b export "$dir/brf" "$dir/export_brf"
}

echo "regression: $old -> $out/old"; runs "$old" "$out/old" >"$out/old.log" 2>&1
echo "regression: $new -> $out/new"; runs "$new" "$out/new" >"$out/new.log" 2>&1
PYTHONPATH=$new/src "$PY" - "$out/old" "$out/new" <<'PY'
import json, sys
from pathlib import Path
import torch
from safetensors.torch import load_file

SKIP = {"allow_outside_links", "backend", "eval_seconds", "train_timings_s", "timings_s", "scene_root", "root",
        "seconds", "simulation_seconds", "config"}  # the options as each version records them

def strip(o):
    if isinstance(o, dict):
        return {k: strip(v) for k, v in o.items() if k not in SKIP}
    return [strip(v) for v in o] if isinstance(o, list) else o

def same_run(a: Path, b: Path) -> bool:
    ok = True
    for f in ["model.safetensors", "checkpoints/stage1.safetensors", "checkpoints/last.safetensors"]:
        if not (a / f).exists() and not (b / f).exists():
            continue
        if (a / f).exists() != (b / f).exists():
            print(f"  {f}: only in one checkout"); ok = False; continue
        ta, tb = load_file(str(a / f)), load_file(str(b / f))
        diff = sorted(set(ta) ^ set(tb)) + [k for k in ta if k in tb and not (ta[k].shape == tb[k].shape
                                                                            and torch.equal(ta[k], tb[k]))]
        print(f"  {f}: {len(ta)} tensors, " + ("bit-identical" if not diff else f"DIFFER: {diff[:8]}"))
        ok &= not diff
    for f in ["metrics.json", "metrics_train.json", "train_log.csv"]:
        if (a / f).exists() and (b / f).exists():
            if f.endswith(".json"):
                same = strip(json.loads((a / f).read_text())) == strip(json.loads((b / f).read_text()))
            else:
                same = (a / f).read_text() == (b / f).read_text()
            print(f"  {f}: " + ("identical" if same else "DIFFER")); ok &= same
    return ok

old, new = Path(sys.argv[1]), Path(sys.argv[2])
ok = True
for run in sorted(p.name for p in old.iterdir() if (p / "model.safetensors").exists()):
    print(run)
    ok &= same_run(old / run, new / run)
print("regression: ALL IDENTICAL" if ok else "regression: SOME DIFFER")
sys.exit(0 if ok else 1)
PY
