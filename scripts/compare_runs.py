"""compare_runs.py A B: model tensors (model file, checkpoints), train_log.csv and metrics.json of the run
folders under A and B (or of two run folders); timings and fields added since are left out."""
import json, sys
from pathlib import Path
from safetensors.torch import load_file
import torch

TIMING = {"allow_outside_links", "backend", "eval_seconds", "train_timings_s", "timings_s", "scene_root", "root", "seconds", "simulation_seconds"}

def strip(o):
    if isinstance(o, dict):
        return {k: strip(v) for k, v in o.items() if k not in TIMING}
    if isinstance(o, list):
        return [strip(v) for v in o]
    return o

def cmp_run(a, b):
    ok = True
    for f in ["model.safetensors", "checkpoints/stage1.safetensors", "checkpoints/last.safetensors"]:
        pa, pb = a / f, b / f
        if not pa.exists() and not pb.exists():
            continue
        if pa.exists() != pb.exists():
            print(f"  {f}: exists {pa.exists()} vs {pb.exists()}"); ok = False; continue
        ta, tb = load_file(str(pa)), load_file(str(pb))
        if set(ta) != set(tb):
            print(f"  {f}: tensor names differ: {sorted(set(ta) ^ set(tb))}"); ok = False
        diff = [k for k in ta if k in tb and not (ta[k].shape == tb[k].shape and torch.equal(ta[k], tb[k]))]
        print(f"  {f}: {len(ta)} tensors, {'all bit-identical' if not diff else 'DIFFER: ' + str(diff[:8])}")
        ok &= not diff
    for f in ["metrics.json", "metrics_train.json"]:
        pa, pb = a / f, b / f
        if pa.exists() and pb.exists():
            ma, mb = strip(json.loads(pa.read_text())), strip(json.loads(pb.read_text()))
            same = ma == mb
            if not same:
                for k in ma:
                    if ma.get(k) != mb.get(k): print(f"    {f} differs at {k}")
            print(f"  {f}: {'identical (timings excluded)' if same else 'DIFFER'}")
            ok &= same
    for f in ["train_log.csv"]:
        pa, pb = a / f, b / f
        if pa.exists() and pb.exists():
            same = pa.read_text() == pb.read_text()
            print(f"  {f}: {'identical' if same else 'DIFFER'}"); ok &= same
    return ok

A, B = Path(sys.argv[1]), Path(sys.argv[2])
runs = [p.name for p in sorted(A.iterdir()) if (p / "model.safetensors").exists()] if not (A / "model.safetensors").exists() else ["."]
allok = True
for r in runs:
    print(r)
    allok &= cmp_run(A / r, B / r)
print("ALL IDENTICAL" if allok else "SOME DIFFER")
