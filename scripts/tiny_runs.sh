#!/usr/bin/env bash
# usage: scripts/tiny_runs.sh SRC OUT -- every variant on a tiny plane scene with the brfgs checkout SRC
# (e.g. a git worktree of an older commit); compare two OUTs with scripts/compare_runs.py.
set -e
SRC=$1; OUT=$2
export PYTHONPATH=$SRC/src:$SRC/tests
rm -rf $OUT; mkdir -p $OUT
python3 - <<PY
import brfgs, sys; print(brfgs.__file__)
from pathlib import Path
from test_train_scene import make_plane_scene
make_plane_scene(Path("$OUT/scene"), w=48, h=32, n_bands=16)
PY
B="python3 -m brfgs"
$B train $OUT/scene $OUT/brf --preset tiny --quiet --threads 1
$B train $OUT/scene $OUT/sh --preset tiny --variant sh --from-stage1 $OUT/brf/checkpoints/stage1.safetensors --quiet --threads 1
$B train $OUT/scene $OUT/neural --preset tiny --variant neural --quiet --threads 1
$B train $OUT/scene $OUT/cir --preset tiny --variant cir --quiet --threads 1
$B train $OUT/scene $OUT/joint --preset tiny --joint --quiet --threads 1
$B train $OUT/scene $OUT/brfcpu --preset tiny --backend cpu --stage1-steps 40 --quiet --threads 1
for r in brf sh neural cir joint brfcpu; do cp $OUT/$r/metrics.json $OUT/$r/metrics_train.json; done
$B evaluate $OUT/brf --quiet --backend torch
$B render $OUT/brf --view-zenith 20 --view-azimuth 45 --out $OUT/render_brf --quiet --backend torch
$B brf $OUT/brf --roi "box:view_00:0,0,16,12" --out $OUT/brf_brf --quiet --backend torch || true
$B products $OUT/brf --out $OUT/prod_brf --quiet --backend torch || true
$B export $OUT/brf $OUT/export_brf || true
echo TINY_DONE
