#!/usr/bin/env bash
# The headline rows of docs/results.md on one copy of the `dense` preset: the zoo recipe with the footprint
# occupancy input (the best CFAR+PFAL configuration), the canonical prior (no network) and PointNet++ (the
# strongest learned baseline), trained at the equal budget and tested with rollouts; each test's report.json and
# report.md are copied to $OUT/<benchmark>/<job>.
#   RUNS=runs/v21 OUT=docs/results/v21 scripts/headline_runs.sh layouts occ 0      # one job: <benchmark> <job> [seed]
#   jobs: occ (curriculum + test), prior (needs occ seed 0's AxisNet), pointnet2 (fit + test), recipe (no occupancy)
set -euo pipefail
SELF=$(realpath "$0")
cd "$(dirname "$SELF")/.."
if ! command -v floaff-zoo > /dev/null && [ -x .venv/bin/floaff-zoo ]; then PATH=$PWD/.venv/bin:$PATH; fi
export MUJOCO_GL=${MUJOCO_GL:-egl} OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
RUNS=${RUNS:?set RUNS, the run root (e.g. runs/v21)}
OUT=${OUT:?set OUT, where reports are copied (e.g. docs/results/v21)}
bench=${1:?benchmark: layouts or styles}
job=${2:?job: occ, recipe, prior or pointnet2}
seed=${3:-0}
case $bench in layouts|styles) ;; *) echo "headline_runs.sh: unknown benchmark '$bench'" >&2; exit 2 ;; esac

# test RUN_DIR LABEL DEST: roll out the best checkpoint of RUN_DIR's fit, label the report, copy it to DEST
test_run() {
  local run=$1 label=$2 dest=$3 eval
  eval=$(mktemp --suffix=.yaml)
  sed "s/^        figures: true/        figures: true\n        label: \"$label\"/" configs/trainer/eval_sr.yaml > "$eval"
  floaff-zoo test --config "$run/config.yaml" --config "$eval" --ckpt_path "${4:-best}"
  rm -f "$eval"
  local rep
  rep=$(ls -td "$(dirname "$run")"/version_*/ | head -1)
  mkdir -p "$dest" && cp "$rep/report.json" "$rep/report.md" "$dest/"
}
latest() { ls -td "$1"/version_*/ | head -1 | sed 's:/$::'; }

case $job in
  occ|recipe)
    name=occ_recipe_s$seed; label="zoo recipe, footprint occupancy input"
    extra=(--extra-config configs/experiments/recipe/cfar_recipe.yaml)
    if [ "$job" = occ ]; then extra+=(--extra-config configs/experiments/recipe/occupancy.yaml)
    else name=recipe_s$seed; label="CFAR+PFAL, zoo recipe"; fi
    floaff-zoo curriculum --config "configs/experiments/pfal_dense_$bench.yaml" --root "$RUNS/$bench/$name" \
      --set "seed_everything=$seed" "${extra[@]}"
    test_run "$(latest "$RUNS/$bench/$name/stage2_door_drawer/cfarmodule")" "$label" "$OUT/$bench/$name" ;;
  prior)
    axis=$(ls "$RUNS/$bench/occ_recipe_s0/axisnet/axisnetmodule/version_0/checkpoints/"epoch*.ckpt | head -1)
    floaff-zoo fit --config "configs/data/floaff_dense_$bench.yaml" --config configs/models/canonical_prior.yaml \
      --model.init_args.axisnet "$axis" --data.init_args.train_transforms '[]' --trainer.max_epochs 1 \
      --trainer.default_root_dir "$RUNS/$bench/prior"
    test_run "$(latest "$RUNS/$bench/prior/canonicalpriormodule")" "Canonical prior (no network)" "$OUT/$bench/prior" last ;;
  pointnet2)
    floaff-zoo fit --config "configs/data/floaff_dense_$bench.yaml" --config configs/demo/pointnet2_demo.yaml \
      --config configs/trainer/dense_budget.yaml --seed_everything "$seed" \
      --trainer.default_root_dir "$RUNS/$bench/pointnet2_s$seed"
    test_run "$(latest "$RUNS/$bench/pointnet2_s$seed/pointnet2module")" "PointNet++" "$OUT/$bench/pointnet2_s$seed" ;;
  *) echo "headline_runs.sh: unknown job '$job' (occ, recipe, prior, pointnet2)" >&2; exit 2 ;;
esac
