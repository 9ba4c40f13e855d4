#!/usr/bin/env bash
# Issue 15's "done when" numbers with one command: simulate the five 49-view scenes (those not yet
# in OUT/scenes), train per scene and seed the default, SH-3 on the default's stage 1 (the same
# stage 2, `--variant sh --from-stage1`) and joint training (`--joint`), render the pond's
# principal plane against the truth, and print the tables of docs/results.md ("Where issue 15
# stands"): each run's test / validation metrics, BRF-GS − SH-3, the SAM ratios, joint, per ring,
# the 18° − 58° gap and the pond; then `brfgs compare --scenes` pooled over the scenes and seeds,
# BRF-GS against SH-3 (test and validation views) and against joint training.
#
#   bash scripts/issue15_targets.sh OUT [SCENES] [SEEDS]
#
#   SCENES  comma list of ts128, ts64, sun20, sun55, forest64 (default: all five, the scenes the
#           defaults were chosen on), or of the scenes no setting was chosen on (Session 29): tsA64,
#           tsB64, tsC64, tsD64, fB64 (other suns, seeds, camera and view layouts)
#   SEEDS   comma list of training seeds (default: 0,1)
#
# Reruns skip what is finished (a scene with transforms.json, a run with metrics.json, a pond
# with brf.json) and resume an interrupted training. Extra `brfgs train` options for every run
# (e.g. "--preset fine") come from BRFGS_TARGETS_TRAIN_ARGS; BRFGS_TARGETS_SIZE simulates every
# scene at that size instead, with BRFGS_TARGETS_SIM_ARGS added (a smoke test of a few minutes:
# BRFGS_TARGETS_SIZE=64 BRFGS_TARGETS_SIM_ARGS="--views 13 --spp 16" BRFGS_TARGETS_TRAIN_ARGS="--preset
# tiny"). Time on 2 CPU cores, one thread per run: ~15 min per 64² simulation and ~45 min for ts128,
# ~15–25 min per default run at 64² (~60 min at 128²), SH-3 ~5–8 min, joint ~15–25 min; one run at a
# time, the whole table with two seeds ~10 h. Tables go to stdout and OUT/targets.md.
set -euo pipefail

out=${1:?usage: bash scripts/issue15_targets.sh OUT [SCENES] [SEEDS]}
IFS=, read -r -a scenes <<< "${2:-ts128,ts64,sun20,sun55,forest64}"
IFS=, read -r -a seeds <<< "${3:-0,1}"
size=${BRFGS_TARGETS_SIZE:-}
read -r -a sim_extra <<< "${BRFGS_TARGETS_SIM_ARGS:-}"
read -r -a extra <<< "${BRFGS_TARGETS_TRAIN_ARGS:-}"
here=$(cd "$(dirname "$0")" && pwd)

sim_args() {  # the simulate options of a scene label (docs/results.md, Sessions 6-7 and 29-30)
  case $1 in
    ts128) echo "--scene testsite --size ${size:-128}" ;;
    ts64) echo "--scene testsite --size ${size:-64}" ;;
    sun20) echo "--scene testsite --size ${size:-64} --sun-zenith 20" ;;
    sun55) echo "--scene testsite --size ${size:-64} --sun-zenith 55" ;;
    forest64) echo "--scene forest --size ${size:-64}" ;;
    tsA64) echo "--scene testsite --size ${size:-64} --sun-zenith 30 --sun-azimuth 240 --seed 3" ;;
    tsB64) echo "--scene testsite --size ${size:-64} --sun-zenith 45 --sun-azimuth 60 --distance 80 --fov 45 --seed 5" ;;
    tsC64) echo "--scene testsite --size ${size:-64} --rings 12,30,45,60 --azimuths 10 --sun-zenith 50 --sun-azimuth 100 --seed 7" ;;
    tsD64) echo "--scene testsite --size ${size:-64} --sun-zenith 65 --sun-azimuth 200 --seed 11" ;;
    fB64) echo "--scene forest --size ${size:-64} --sun-zenith 45 --sun-azimuth 60 --seed 5" ;;
    *) echo "issue15_targets: unknown scene '$1' (ts128, ts64, sun20, sun55, forest64, tsA64, tsB64, tsC64, tsD64, fB64)" >&2
       exit 2 ;;
  esac
}

train() {  # RUN SCENE [OPTIONS...]: train unless finished (rerun resumes an interrupted one)
  local run=$1 scene=$2
  shift 2
  if [ -f "$run/metrics.json" ]; then echo "finished: $run"; return; fi
  echo "train: $run"
  brfgs train "$scene" "$run" --validation --threads 1 --quiet "${extra[@]}" "$@"
}

for s in "${scenes[@]}"; do sim_args "$s" > /dev/null; done  # check every label before any work
mkdir -p "$out/scenes" "$out/runs"
a_runs=() b_runs=() j_runs=() pond=()
for s in "${scenes[@]}"; do
  scene=$out/scenes/$s
  if [ ! -f "$scene/transforms.json" ]; then
    echo "simulate: $scene"
    # shellcheck disable=SC2046
    if [ -d "$scene" ]; then brfgs simulate "$scene" $(sim_args "$s") "${sim_extra[@]}" --quiet --resume
    else brfgs simulate "$scene" $(sim_args "$s") "${sim_extra[@]}" --quiet; fi
  fi
  for seed in "${seeds[@]}"; do
    dir=$out/runs/${s}_s$seed
    train "$dir/default" "$scene" --seed "$seed"
    train "$dir/sh" "$scene" --seed "$seed" --variant sh --from-stage1 "$dir/default/checkpoints/stage1.safetensors"
    train "$dir/joint" "$scene" --seed "$seed" --joint
    a_runs+=("$dir/default") b_runs+=("$dir/sh") j_runs+=("$dir/joint")
    # the pond, on the testsites (the forest has no water)
    if [[ $(sim_args "$s") == *"--scene testsite"* ]] && [ ! -f "$dir/default/analysis/brf_water/brf.json" ]; then
      brfgs brf "$dir/default" --roi material:water --bands 480,860 --no-polar --truth-size 64 --truth-spp 16 --quiet
    fi
    pond+=("${s}_s$seed=$dir")
  done
done

{
  echo "## Per scene and seed (test views against the truth)"
  echo
  python "$here/scene_margins.py" "${pond[@]}"
  echo
  for split in test validation; do
    echo "## BRF-GS − SH-3 over the scenes, $split views (\`brfgs compare … --scenes --split $split\`)"
    echo
    echo '```'
    brfgs compare "$(IFS=,; echo "${a_runs[*]}")" "$(IFS=,; echo "${b_runs[*]}")" --scenes --split "$split"
    echo '```'
    echo
  done
  echo "## Decoupled − joint training over the scenes, test views (the SAM ratio should be below 1)"
  echo
  echo '```'
  brfgs compare "$(IFS=,; echo "${a_runs[*]}")" "$(IFS=,; echo "${j_runs[*]}")" --scenes --split test
  echo '```'

} | tee "$out/targets.md"
