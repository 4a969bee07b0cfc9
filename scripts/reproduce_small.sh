#!/usr/bin/env bash
# The experiments of docs/results.md and docs/results_history.md on a 2-core CPU machine, two jobs at a time.
#
#   scripts/reproduce_small.sh                 # every job, in the order of JOBS below
#   scripts/reproduce_small.sh cfar_pfal_s0 pointnet2_s0   # only these
#   PAR=1 scripts/reproduce_small.sh ...       # one at a time (each job then may use both cores)
#   RETEST=1 scripts/reproduce_small.sh ...    # only test the finished runs again (e.g. after adding test scenes)
#   RETEST=1 EVAL=configs/trainer/eval_sr_top10_full.yaml PRESET=dense RUNS=runs/v21 OUT=docs/results/v21_fullcloud \
#     scripts/reproduce_small.sh pool_succ_occ_recipe_s0 ...   # test again with other evaluation callbacks (here the
#                                              # best of the top 10 cells free in the whole stored cloud)
#   PRESET=dense RUNS=runs/regen OUT=docs/results/regen scripts/reproduce_small.sh recipe_s0 recipe_edges_s0 \
#     prior prior_edges styles_recipe_s0 styles_recipe_edges_s0 ...   # the prior's cells, centred vs edge-binned
#                                              # (docs/results_history.md, "Regenerated dense data")
#   EPOCHS=6 scripts/reproduce_small.sh navaff # baselines for another number of epochs (default 20)
#   PRESET=dense scripts/reproduce_small.sh recipe_s0 prior pointnet2_s0   # the dense preset's equal-budget
#                                              # protocol (4,000 samples per learned model; docs/results.md)
#   PRESET=dense DATA_ROOT=data/floaff_dense05 RUNS=runs/grid05 OUT=docs/results/grid05 \
#     scripts/reproduce_small.sh occ_recipe_s0 styles_occ_recipe_s0 prior styles_prior  # the same protocol on
#                                              # another copy of the data (here the 0.05 m grid; every fit, curriculum
#                                              # stage and training-free test reads DATA_ROOT); AXIS_JOB names the
#                                              # curriculum whose AxisNet the prior uses (default recipe_s0)
#   PRESET=dense scripts/reproduce_small.sh recipe_no_crop styles_recipe_r1.30   # ablations / crop sweep on
#                                              # top of the zoo recipe (recipe_no_{crop,align,sdl,fd}, recipe_r1.xx,
#                                              # each also as styles_<job>; other seeds: recipe_no_crop_s1,
#                                              # recipe_r1.10_s2, ...); occ_recipe_no_{crop,align,sdl,fd}[_s<seed>]
#                                              # (and styles_...) ablate the best configuration (recipe + occupancy),
#                                              # occ_recipe_r1.xx[_s<seed>] sweep its crop radius,
#                                              # rank_occ_recipe_s<seed> adds the listwise ranking term;
#                                              # succ_occ_recipe_s<seed> / succ_prior train on labels with failed
#                                              # cells set to 0; pool_succ_occ_recipe_s<seed> / pool_succ_prior
#                                              # the same refit on every train scene (no validation scene),
#                                              # pool_<model>_s<seed> (pointnet2, navaff, votenet, h3dnet,
#                                              # n2m, cfar_pfal: the paper's path) the other learned models on it,
#                                              # pool_succ_occ_recipe_no_{crop,align,sdl,fd}[_s<seed>] its ablations,
#                                              # pool_succ_occ_recipe_r1.xx[_s<seed>] its crop sweep;
#                                              # cv<f>_{occ,rank,prior,last,succ,sprior,cov,cos} (and styles_...): leave-one-layout-out folds
#                                              # f = 0..4 scored on their validation scenes (scripts/cv_sr.py pools them;
#                                              # CV_SEED=<n> trains them with another seed, default 0: give it its own
#                                              # RUNS and OUT);
#                                              # occ_recipe_rs<scale>_s<seed> tests the best configuration with its
#                                              # learned residual scaled (no training)
#                                              # st_<task>_<model>_s<seed> (and styles_...): one model per task, no
#                                              # PFAL, the paper's Table 3 (single_task below)
#
# Needs the data:
#   floaff-zoo generate --preset small --benchmarks layouts styles --out data/floaff_small --workers 2 --n-test 4
# Every job trains (a `fit` or a PFAL `curriculum`), tests on all four tasks with the rollout success-rate
# callback, and copies its report.json/report.md to $OUT/<benchmark>/<job>/ (default docs/results/small_v2 for
# PRESET=small, docs/results/<preset> otherwise; machine paths stripped). A job whose report is already there is
# skipped; a killed job resumes (the curriculum skips finished stages, fit resumes from last.ckpt).
# Logs: $RUNS/logs/<job>.log (default runs/small_v2, runs/<preset>).
# Then: scripts/results_tables.sh (the tables and pictures of docs/results.md).
# Order matters for the diagnostic jobs: gtyaw_*, stage1_*, axisnet_longer need cfar_pfal_s<seed> finished,
# axis100_* need axisnet_longer (a job whose input is missing fails with a message; rerun it later).
# The whole script is one brace group ending in exit: bash parses all of it before running any of it, so editing this
# file while jobs run (each job is a new process of it) cannot hand a job in flight a half-read line.
{
set -euo pipefail
SELF=$(realpath "$0")
cd "$(dirname "$SELF")/.."
# the project's virtual environment (make setup) when floaff-zoo is not on PATH
if ! command -v floaff-zoo > /dev/null && [ -x .venv/bin/floaff-zoo ]; then PATH=$PWD/.venv/bin:$PATH; fi

FZ=${FZ:-floaff-zoo}
PRESET=${PRESET:-small}
if [ "$PRESET" = small ]; then RUNS=${RUNS:-runs/small_v2} OUT=${OUT:-docs/results/small_v2}
else RUNS=${RUNS:-runs/$PRESET} OUT=${OUT:-docs/results/$PRESET}; fi
# one-stage models: epochs on the small preset, the equal sample budget on the dense one
if [ "$PRESET" = dense ]; then BUDGET=(--config configs/trainer/dense_budget.yaml)
else BUDGET=(--trainer.max_epochs "${EPOCHS:-20}"); fi
PAR=${PAR:-2}
CV_SEED=${CV_SEED:-0}  # seed of the leave-one-layout-out fold jobs (cv<f>_*)
# DATA_ROOT: a copy of the preset's data other than the one its data configs name (e.g. generated with --cell 0.05)
ROOT_ARGS=() ROOT_SET=()
if [ -n "${DATA_ROOT:-}" ]; then ROOT_ARGS=(--data.init_args.root "$DATA_ROOT") ROOT_SET=(--set "data.init_args.root=$DATA_ROOT"); fi
TASKS='["PnPCounterToCab","OpenSingleDoor","CloseDrawer","CloseDoubleDoor"]'
EVAL=${EVAL:-configs/trainer/eval_sr.yaml}

JOBS=(
  recipe_s0 prior prior_gtyaw cfar_pfal_s0 pointnet2_s0 c2f_exp c2f_exp_gtyaw
  recipe_s1 recipe_s2
  cfar_pfal_s1 pointnet2_s1 cfar_pfal_s2 pointnet2_s2
  navaff votenet h3dnet n2m
  no_crop no_align no_sdl no_fd
  styles_cfar_pfal styles_pointnet2 styles_c2f_exp
  axisnet_longer gtyaw_s0 gtyaw_s1 gtyaw_s2 stage1_s0 stage1_s1 stage1_s2
  r1.10 r1.30 r1.40 r1.15 r1.25 r1.35
  axis100_s0 axis100_s1 axis100_s2
  recipe_no_prior recipe_no_snap recipe_pointwise recipe_no_fd
  styles_recipe styles_prior styles_recipe_s1 styles_recipe_s2
)
RECIPE=configs/experiments/recipe/cfar_recipe.yaml

# test_run RUN_DIR LABEL BENCH JOB [CKPT [TEST ARGS...]]: test a fit run on all tasks, copy its report
test_run() {
  local run=$1 label=$2 bench=$3 job=$4 ckpt=${5:-best}; shift 5 || shift $#
  if [ "${TRAIN_ONLY:-0}" = 1 ]; then echo "$job: trained, not tested (TRAIN_ONLY=1)"; return 0; fi
  local before=$run/../.tested_$job
  touch "$before"
  "$FZ" test --config "$run/config.yaml" --config "$EVAL" --data.init_args.tasks "$TASKS" \
    --ckpt_path "$ckpt" --trainer.callbacks.init_args.label "$label" "$@"
  # the report lands in the next version_<n> beside the fit run: the one written since, with this job's label (jobs
  # testing one run at once, e.g. occ_recipe_rs<a>_s<n> and occ_recipe_rs<b>_s<n>, write theirs beside it too)
  local report
  report=$(find "$run/.." -name report.json -newer "$before" -print0 | xargs -0 -r python3 -c '
import json, sys
def label_of(f):
    try:
        return json.load(open(f)).get("label")
    except ValueError:  # another job'"'"'s report, half written
        return None
label, files = sys.argv[1], sys.argv[2:]
print(next((f for f in files if label_of(f) == label), ""))' "$label")
  copy_report "$report" "$bench" "$job"
}

# copy_report REPORT_JSON BENCH JOB: report.json + report.md to $OUT/BENCH/JOB/, machine paths stripped
copy_report() {
  [ -n "$1" ] || { echo "no report.json written for $3" >&2; return 1; }
  mkdir -p "$OUT/$2/$3"
  # paths relative to this checkout and to the one OUT lies in: run from a git worktree with DATA_ROOT, RUNS and OUT
  # in the main checkout, the reports named that machine's folders
  local dest strip=(-e "s#$PWD/##g")
  dest=$(git -C "$OUT" rev-parse --show-toplevel 2> /dev/null) && [ "$dest" != "$PWD" ] && strip+=(-e "s#$dest/##g")
  sed "${strip[@]}" "$1" > "$OUT/$2/$3/report.json"
  sed "${strip[@]}" "$(dirname "$1")/report.md" > "$OUT/$2/$3/report.md"
}

# newest fit run (the directory holding checkpoints/last.ckpt) under a root
latest_run() { dirname "$(find "$1" -name last.ckpt -printf '%T@ %h\n' | sort -n | tail -n 1 | cut -d' ' -f2)"; }
RETEST=${RETEST:-0}

# stage_ckpt RUN_ROOT INDEX: the best checkpoint of a curriculum's stage (0 = the first, -1 = the last; the last only
# of a curriculum whose every stage finished: lineage.json's "complete")
stage_ckpt() {
  python3 -c "import json,sys; l=json.load(open(sys.argv[1])); i=int(sys.argv[2])
if i < 0 and l.get('complete') is False: sys.exit(sys.argv[1] + ': the curriculum did not finish')
print(l['stages'][i]['checkpoint'])" "$1/lineage.json" "$2"
}

# wait_axisnet RUN_ROOT JOB: the AxisNet checkpoint (stage 0) of the curriculum under RUN_ROOT, waiting up to 30 minutes
# for a job running beside this one to write it
wait_axisnet() {
  local axis="" tries=0
  until axis=$(stage_ckpt "$1" 0 2>/dev/null) && [ -f "$axis" ]; do
    tries=$((tries + 1)); [ $tries -le 180 ] || { echo "$2: no AxisNet in $1/lineage.json (run that curriculum)" >&2; return 1; }
    sleep 10
  done
  echo "$axis"
}

# cv_score JOB BENCH FOLD NAME=CKPT [NAME=CKPT ...]: SR on the validation scenes of a leave-one-layout-out fold (scripts/scene_sr.py),
# to $OUT/cv/BENCH/JOB.json; scripts/cv_sr.py pools the folds
cv_score() {
  mkdir -p "$OUT/cv/$2"
  python3 scripts/scene_sr.py --root "${DATA_ROOT:-data/floaff_$PRESET}" --benchmark "$2" --split val --val-layout "$3" \
    --json "$OUT/cv/$2/$1.json" "${@:4}"
}

# success_labels BENCH: the train labels with failed cells set to 0 (configs/experiments/recipe/success_labels_BENCH.yaml
# reads them), made from the annotation (no rollout, seconds); written aside and moved, so jobs running beside it never
# read half a file. The file's name holds no data copy, so every call makes the labels of DATA_ROOT aside and keeps
# the file only if it holds the same ones: a file of another copy was silently trained on before; it is refused (not
# replaced: jobs beside this one may be reading it)
success_labels() {
  local f=runs/labels/success_train_$1.npz root=${DATA_ROOT:-data/floaff_$PRESET}
  mkdir -p runs/labels
  python3 scripts/fresh_labels.py --root "$root" --benchmark "$1" --episodes 0 --zero-failures --out "$f.$$.npz" || return 1
  # (each step checks its status: run_job runs inside an `if`, where set -e does not stop a failed command)
  # -n: of two jobs starting at once, the first keeps its file and the second compares against it
  mv -n "$f.$$.npz" "$f"; [ -f "$f.$$.npz" ] || return 0
  # 0: the same labels; 2: the same labels in a file written before it recorded the data it was made from
  # (setting.made_from), kept as it is: a new file would change its sha256, which every finished stage that trained
  # on it records, and re-fit them all (the fits warn that it is unchecked); 1: other labels
  local same=0
  python3 -c 'import json, sys, numpy as np
a, b = np.load(sys.argv[1]), np.load(sys.argv[2])
if sorted(a.files) != sorted(b.files) or not all(np.array_equal(a[k], b[k]) for k in a.files if k != "setting"):
    sys.exit(1)
sa, sb = json.loads(str(a["setting"])), json.loads(str(b["setting"]))
if sa == sb:
    sys.exit(0)
sb.pop("made_from", None)
sys.exit(2 if "made_from" not in sa and sa == sb else 1)' "$f" "$f.$$.npz" || same=$?
  if [ "$same" = 0 ] || [ "$same" = 2 ]; then rm -f "$f.$$.npz"; return 0; fi
  rm -f "$f.$$.npz"
  echo "$f holds other labels than $root gives now (another copy of the data, or labels made by other code):" \
    "delete it (with no job reading it) to make it from $root, or run one copy at a time" >&2
  return 1
}

# curriculum JOB BENCH SEED LABEL [--extra-config FILE]: PFAL, then test the last stage's best
curriculum() {
  local job=$1 bench=$2 seed=$3 label=$4; shift 4
  if [ "$RETEST" = 0 ]; then
    "$FZ" curriculum --config "configs/experiments/pfal_${PRESET}_$bench.yaml" --root "$RUNS/$bench/$job" \
      --set "seed_everything=$seed" "${ROOT_SET[@]}" "$@"
  fi
  local ckpt stage
  ckpt=$(stage_ckpt "$RUNS/$bench/$job" -1)
  stage=$(dirname "$(dirname "$ckpt")")
  test_run "$stage" "$label" "$bench" "$job" "$ckpt"
}

# stage_test JOB SOURCE_JOB STAGE_INDEX LABEL [TEST ARGS...]: test one stage of a finished curriculum again
# with other evaluation settings (diagnostics; no training)
stage_test() {
  local job=$1 src=$2 idx=$3 label=$4; shift 4
  local ckpt
  ckpt=$(stage_ckpt "$RUNS/layouts/$src" "$idx")
  test_run "$(dirname "$(dirname "$ckpt")")" "$label" layouts "$job" "$ckpt" "$@"
}

# baseline JOB BENCH SEED MODEL_CONFIG LABEL [FIT ARGS...]: fit (resumed from last.ckpt when killed), then test
baseline() {
  local job=$1 bench=$2 seed=$3 model=$4 label=$5 root=$RUNS/$2/$1 last=(); shift 5
  if [ -d "$root" ]; then
    local prev; prev=$(find "$root" -name last.ckpt | head -n 1)
    if [ -n "$prev" ]; then last=(--ckpt_path "$prev"); fi
  fi
  if [ "$RETEST" = 0 ]; then
    "$FZ" fit --config "configs/data/floaff_${PRESET}_$bench.yaml" --config "$model" \
      --seed_everything "$seed" --trainer.default_root_dir "$root" "${BUDGET[@]}" "${ROOT_ARGS[@]}" "$@" "${last[@]}"
  fi
  test_run "$(latest_run "$root")" "$label" "$bench" "$job"
}

# training-free C2F-Exp-style: test only (TRAINING_FREE LABEL [TEST ARGS...] after JOB BENCH)
training_free() {
  local job=$1 bench=$2 label=${3:-C2F-Exp} root=$RUNS/$2/$1; shift 3 || shift $#
  local before=$RUNS/.tested_${bench}_$job
  mkdir -p "$RUNS"; touch "$before"
  "$FZ" test --config "configs/data/floaff_${PRESET}_$bench.yaml" --config configs/models/c2f_exp.yaml \
    --config "$EVAL" --trainer.default_root_dir "$root" --trainer.callbacks.init_args.label "$label" "${ROOT_ARGS[@]}" "$@"
  copy_report "$(find "$root" -name report.json -newer "$before" | head -n 1)" "$bench" "$job"
}

# prior JOB BENCH LABEL [TEST ARGS...]: the canonical prior (one pass over the training labels) with the AxisNet of
# the recipe's seed-0 curriculum inside its checkpoint (job recipe_s0 first; waited for when it runs in parallel)
prior() {
  local job=$1 bench=$2 label=$3 root=$RUNS/$2/prior fit=(); shift 3
  case $job in
    *_edges) root=$RUNS/$bench/prior_edges fit=(--model.init_args.centred false) ;;
    fresh_*) root=$RUNS/$bench/$job fit=(--config "configs/experiments/recipe/fresh_labels_$bench.yaml") ;;
    succ_*) root=$RUNS/$bench/$job fit=(--config "configs/experiments/recipe/success_labels_$bench.yaml") ;;
    pool_succ_*) root=$RUNS/$bench/$job fit=(--config "configs/experiments/recipe/success_labels_$bench.yaml"
      --data.init_args.val_scenes 0) ;;
    # mirrored views: 4 passes, each view reflected with probability 0.5, so the average is near-symmetric
    mirror_*) root=$RUNS/$bench/$job fit=(--config configs/experiments/recipe/mirror.yaml --trainer.max_epochs 4) ;;
  esac
  local axis; axis=$(wait_axisnet "$RUNS/$bench/${AXIS_JOB:-recipe_s0}" "$job") || return 1
  if [ "$RETEST" = 0 ] && [ -z "$(find "$root" -name last.ckpt 2>/dev/null)" ]; then
    "$FZ" fit --config "configs/data/floaff_${PRESET}_$bench.yaml" --config configs/models/canonical_prior.yaml \
      --model.init_args.axisnet "$axis" --data.init_args.train_transforms '[]' --trainer.max_epochs 1 \
      --trainer.default_root_dir "$root" "${ROOT_ARGS[@]}" "${fit[@]}"
  fi
  test_run "$(latest_run "$root")" "$label" "$bench" "$job" last "$@"
}

# axisnet_longer: AxisNet trained 100 epochs with a cosine schedule (the PFAL recipe trains 30), and the test
# angle error per task of both; the CFAR+PFAL models are then tested with it (axis100_s<seed>): training
# uses the simulator's yaw, so only the estimator used at test time changes
axisnet_longer() {
  local root=$RUNS/layouts/axisnet100 out=$OUT/layouts/axisnet_yaw_error.md
  if [ "$RETEST" = 0 ] && [ -z "$(find "$root" -name last.ckpt 2>/dev/null)" ]; then
    "$FZ" fit --config configs/data/floaff_small_layouts.yaml --config configs/models/axisnet.yaml \
      --model.init_args.crop_radius 1.2 --model.init_args.train.lr 0.001 --model.init_args.train.scheduler cosine \
      --data.init_args.batch_size 8 --data.init_args.train_transforms '[]' --trainer.max_epochs 100 \
      --trainer.default_root_dir "$root"
  fi
  local new old
  new=$(find "$root" -name 'epoch*.ckpt' | head -n 1)
  old=$(stage_ckpt "$RUNS/layouts/cfar_pfal_s0" 0)
  { echo "| AxisNet | $(echo "$TASKS" | tr -d '[]"' | sed 's/,/ | /g') |"; echo "|---|---:|---:|---:|---:|"; } > "$out.tmp"
  local ck name row t err
  for ck in "$old" "$new"; do
    name="30 epochs (PFAL recipe, seed 0)"; [ "$ck" = "$new" ] && name="100 epochs, cosine"
    row="| $name |"
    for t in PnPCounterToCab OpenSingleDoor CloseDrawer CloseDoubleDoor; do
      err=$("$FZ" test --config "$(dirname "$(dirname "$ck")")/config.yaml" --ckpt_path "$ck" \
        --data.init_args.tasks "[$t]" --trainer.logger.init_args.save_dir "$RUNS/layouts/axisnet_test" \
        --trainer.enable_progress_bar false 2>/dev/null | awk '/test_angle_error_deg/ {print $2}')
      row="$row $(printf '%.1f' "$err")° |"
    done
    echo "$row" >> "$out.tmp"
  done
  mv "$out.tmp" "$out"
}

# pfal_crop_radius BENCH: CFAR's crop radius in the preset's PFAL config of BENCH (its top-level overrides)
pfal_crop_radius() {
  python3 -c "import sys, yaml; c = yaml.safe_load(open(sys.argv[1]))
r = (c.get('overrides') or {}).get('model.init_args.crop_radius')
sys.exit(sys.argv[1] + ': no model.init_args.crop_radius override') if r is None else print(r)" \
    "configs/experiments/pfal_${PRESET}_$1.yaml"
}

# single_task JOB: the paper's Table 3 protocol, one model per task and no PFAL (docs/results.md, "One model per
# task"). JOB = [styles_]st_<task>_<model>_s<seed>, task pnp | osd | drawer | cdd, model cfar (the paper's CFAR path
# without PFAL), cfar_best (the best configuration's network without PFAL: zoo recipe + footprint occupancy + failed
# cells 0), pointnet2 | navaff | votenet | h3dnet | n2m. Whole training pool, 1,000 samples each: PFAL's per-task
# share of the equal budget (stage 1 gives PnPCounterToCab 1,000, stage 2 each door or drawer task 1,000), so
# `st_pnp_cfar_s<n>` is PFAL's stage 1 on the whole pool. Tested on its own task. CFAR takes the benchmark's crop
# radius from its PFAL config and the frozen AxisNet of the curriculum pool_cfar_pfal_s<seed> (cfar) or
# pool_succ_occ_recipe_s<seed> (cfar_best) under AXIS_RUNS (default RUNS): run that job first.
single_task() {
  local b j; split_job
  local rest=${j#st_} short model seed task
  short=${rest%%_*} rest=${rest#*_}
  case $rest in *_s[0-9]) seed=${rest##*_s} model=${rest%_s*} ;; *) echo "$job: no seed (st_<task>_<model>_s<seed>)" >&2; return 2 ;; esac
  case $short in
    pnp) task=PnPCounterToCab ;; osd) task=OpenSingleDoor ;; drawer) task=CloseDrawer ;; cdd) task=CloseDoubleDoor ;;
    *) echo "$job: unknown task '$short' (pnp, osd, drawer, cdd)" >&2; return 2 ;;
  esac
  # test_run reads TASKS: this job tests its own task only
  local TASKS="[\"$task\"]"
  local one=(--data.init_args.tasks "[$task]" --data.init_args.val_scenes 0 --trainer.max_steps 250)
  case $model in
    cfar|cfar_best)
      local src=pool_cfar_pfal_s$seed label="CFAR (no PFAL), single task" extra=() axis
      if [ "$model" = cfar_best ]; then
        success_labels "$b" || return 1
        src=pool_succ_occ_recipe_s$seed label="CFAR, best configuration without PFAL, single task"
        extra=(--config "$RECIPE" --config configs/experiments/recipe/occupancy.yaml
          --config "configs/experiments/recipe/success_labels_$b.yaml")
      fi
      axis=$(stage_ckpt "${AXIS_RUNS:-$RUNS}/$b/$src" 0) || { echo "$job: run $src first (its AxisNet)" >&2; return 1; }
      # the curriculum's radius for this benchmark (Layouts 1.2 m, Styles 1.3 m, as the paper), not the demo config's
      local radius; radius=$(pfal_crop_radius "$b") || return 1
      baseline "$j" "$b" "$seed" configs/demo/cfar_demo.yaml "$label" --model.init_args.axisnet "$axis" \
        --model.init_args.crop_radius "$radius" "${extra[@]}" "${one[@]}" ;;
    pointnet2|navaff|votenet|h3dnet|n2m)
      baseline "$j" "$b" "$seed" "configs/demo/${model}_demo.yaml" "$(label_of "$model"), single task" "${one[@]}" ;;
    *) echo "$job: unknown model '$model' (cfar, cfar_best, pointnet2, navaff, votenet, h3dnet, n2m)" >&2; return 2 ;;
  esac
}

label_of() {  # table label of a baseline model name
  case $1 in pointnet2) echo "PointNet++" ;; navaff) echo NavAff ;; votenet) echo VoteNet ;; h3dnet) echo H3DNet ;;
    n2m) echo N2M ;; *) echo "$1" ;; esac
}

# split_job: the benchmark (b) and the job name without its styles_ prefix (j) of $job, set in the caller's locals
split_job() { b=layouts j=$job; if [ "${job#styles_}" != "$job" ]; then b=styles j=${job#styles_}; fi; }

run_job() {
  local job=$1
  case $job in
    cfar_pfal_s[0-9]) curriculum "$job" layouts "${job#cfar_pfal_s}" "CFAR+PFAL" ;;
    pointnet2_s[0-9]) baseline "$job" layouts "${job#pointnet2_s}" configs/demo/pointnet2_demo.yaml "PointNet++" ;;
    navaff)  baseline navaff layouts 0 configs/demo/navaff_demo.yaml NavAff ;;
    votenet) baseline votenet layouts 0 configs/demo/votenet_demo.yaml VoteNet ;;
    h3dnet)  baseline h3dnet layouts 0 configs/demo/h3dnet_demo.yaml H3DNet ;;
    n2m)     baseline n2m layouts 0 configs/demo/n2m_demo.yaml N2M ;;
    navaff_s[0-9]|votenet_s[0-9]|h3dnet_s[0-9]|n2m_s[0-9])  # any seed of a baseline (<model>_s<seed>)
      baseline "$job" layouts "${job##*_s}" "configs/demo/${job%_s*}_demo.yaml" "$(label_of "${job%_s*}")" ;;
    styles_pointnet2_s[0-9]|styles_navaff_s[0-9]|styles_votenet_s[0-9]|styles_h3dnet_s[0-9]|styles_n2m_s[0-9])
      local m=${job#styles_}; m=${m%_s*}
      baseline "${job#styles_}" styles "${job##*_s}" "configs/demo/${m}_demo.yaml" "$(label_of "$m")" ;;
    styles_cfar_pfal_s[0-9]) curriculum "cfar_pfal_s${job##*_s}" styles "${job##*_s}" "CFAR+PFAL" ;;
    c2f_exp) training_free c2f_exp layouts C2F-Exp ;;
    c2f_exp_gtyaw) training_free c2f_exp_gtyaw layouts "C2F-Exp, simulator yaw" --model.init_args.yaw_source gt ;;
    recipe_s[0-9]) curriculum "$job" layouts "${job#recipe_s}" "CFAR+PFAL, zoo recipe" --extra-config "$RECIPE" ;;
    recipe_no_prior|recipe_no_snap|recipe_pointwise)
      local abl=${job#recipe_} label="recipe w/o ${job#recipe_no_}"
      [ "$abl" = pointwise ] && abl=pointwise_floor label="recipe, pointwise floor"
      curriculum "$job" layouts 0 "$label" --extra-config "$RECIPE" \
        --extra-config "configs/experiments/recipe/$abl.yaml" ;;
    recipe_no_crop|recipe_no_align|recipe_no_sdl|recipe_no_fd|styles_recipe_no_crop|styles_recipe_no_align|\
    styles_recipe_no_sdl|styles_recipe_no_fd|recipe_no_*_s[0-9]|styles_recipe_no_*_s[0-9])
      # the ablations of Tables 4-5 on top of the zoo recipe; seed 0 without suffix, other seeds as _s<seed>
      local b j seed=0 abl; split_job
      abl=${j#recipe_}
      case $abl in *_s[0-9]) seed=${abl##*_s} abl=${abl%_s*} ;; esac
      case $abl in no_crop|no_align|no_sdl|no_fd) ;; *) echo "unknown ablation '$abl'" >&2; return 2 ;; esac
      curriculum "$j" "$b" "$seed" "recipe w/o ${abl#no_}" --extra-config "$RECIPE" \
        --extra-config "configs/experiments/ablations/$abl.yaml" ;;
    occ_recipe_no_*|styles_occ_recipe_no_*|pool_succ_occ_recipe_no_*|styles_pool_succ_occ_recipe_no_*)
      # the same ablations on top of the best configuration (recipe + footprint occupancy input), or with pool_succ_
      # on top of the headline one (also failed cells 0 in training, refit on the whole training pool)
      local b j seed=0 abl label="occupancy recipe" pre=() post=(); split_job
      abl=${j#*occ_recipe_}
      case $abl in *_s[0-9]) seed=${abl##*_s} abl=${abl%_s*} ;; esac
      case $abl in no_crop|no_align|no_sdl|no_fd) ;; *) echo "unknown ablation '$abl'" >&2; return 2 ;; esac
      if [ "${j#pool_succ_}" != "$j" ]; then
        success_labels "$b" || return 1; label="whole-pool configuration"
        pre=(--set data.init_args.val_scenes=0) post=(--extra-config "configs/experiments/recipe/success_labels_$b.yaml")
      fi
      curriculum "$j" "$b" "$seed" "$label w/o ${abl#no_}" "${pre[@]}" --extra-config "$RECIPE" \
        --extra-config configs/experiments/recipe/occupancy.yaml "${post[@]}" \
        --extra-config "configs/experiments/ablations/$abl.yaml" ;;
    recipe_r1.[0-9]*|styles_recipe_r1.[0-9]*|occ_recipe_r1.[0-9]*|styles_occ_recipe_r1.[0-9]*|\
    pool_succ_occ_recipe_r1.[0-9]*|styles_pool_succ_occ_recipe_r1.[0-9]*)
      # the crop sweep (CFAR's radius only) on top of the zoo recipe, with occ_ on top of the best configuration
      # (recipe + footprint occupancy input), with pool_succ_occ_ on top of the headline one (also failed cells 0 in
      # training, refit on the whole training pool); seed 0 without suffix, other seeds as recipe_r1.xx_s<seed>;
      # the run is named as job_out says (recipe_r1.xx -> recipe_sweep_r1.xx)
      local b j seed=0 r label=recipe pre=() post=(); split_job
      case $j in
        occ_*) label="occupancy recipe" post=(--extra-config configs/experiments/recipe/occupancy.yaml) ;;
        pool_succ_occ_*)
          success_labels "$b" || return 1; label="whole-pool configuration" pre=(--set data.init_args.val_scenes=0)
          post=(--extra-config configs/experiments/recipe/occupancy.yaml
            --extra-config "configs/experiments/recipe/success_labels_$b.yaml") ;;
      esac
      r=${j#*recipe_}
      case $r in *_s[0-9]) seed=${r##*_s} r=${r%_s*} ;; esac
      [ -f "configs/experiments/sweep_crop/$r.yaml" ] || { echo "unknown sweep radius '$r'" >&2; return 2; }
      curriculum "${j/recipe_r/recipe_sweep_r}" "$b" "$seed" "$label, r=${r#r}" "${pre[@]}" --extra-config "$RECIPE" \
        "${post[@]}" --extra-config "configs/experiments/sweep_crop/$r.yaml" ;;
    prior) prior prior layouts "Canonical prior (no network)" ;;
    prior_gtyaw) prior prior_gtyaw layouts "Canonical prior, simulator yaw" --model.init_args.eval_yaw_source gt ;;
    styles_recipe) curriculum recipe_s0 styles 0 "CFAR+PFAL, zoo recipe" --extra-config "$RECIPE" ;;
    styles_recipe_s[0-9]) curriculum "recipe_s${job#styles_recipe_s}" styles "${job#styles_recipe_s}" "CFAR+PFAL, zoo recipe" \
      --extra-config "$RECIPE" ;;
    styles_prior) prior prior styles "Canonical prior (no network)" ;;
    # trained on repeated-episode labels (scripts/fresh_labels.py first; docs/results.md)
    fresh_recipe_s[0-9]|styles_fresh_recipe_s[0-9])
      local b j; split_job
      curriculum "$j" "$b" "${j#fresh_recipe_s}" "zoo recipe, repeated-episode labels" --extra-config "$RECIPE" \
        --extra-config "configs/experiments/recipe/fresh_labels_$b.yaml" ;;
    fresh_prior) prior fresh_prior layouts "Canonical prior, repeated-episode labels" ;;
    # trained on the labels with failed cells set to 0 (configs/experiments/recipe/success_labels_<bench>.yaml;
    # docs/results.md): the best configuration, and the canonical prior filled from them
    succ_occ_recipe_s[0-9]|styles_succ_occ_recipe_s[0-9])
      local b j; split_job
      success_labels "$b" || return 1
      curriculum "$j" "$b" "${j#succ_occ_recipe_s}" "occupancy recipe, failed cells 0 in training" --extra-config "$RECIPE" \
        --extra-config configs/experiments/recipe/occupancy.yaml --extra-config "configs/experiments/recipe/success_labels_$b.yaml" ;;
    succ_prior|styles_succ_prior)
      local b j; split_job
      success_labels "$b" || return 1; prior succ_prior "$b" "Canonical prior, failed cells 0" ;;
    # the best configuration and its prior refit on the whole training pool: every train scene trains (val_scenes 0,
    # every stage, AxisNet included), no validation, each stage's last checkpoint (docs/results.md)
    pool_succ_occ_recipe_s[0-9]|styles_pool_succ_occ_recipe_s[0-9])
      local b j; split_job
      success_labels "$b" || return 1
      curriculum "$j" "$b" "${j#pool_succ_occ_recipe_s}" "occupancy recipe, failed cells 0, whole training pool" \
        --set data.init_args.val_scenes=0 --extra-config "$RECIPE" --extra-config configs/experiments/recipe/occupancy.yaml \
        --extra-config "configs/experiments/recipe/success_labels_$b.yaml" ;;
    pool_succ_prior|styles_pool_succ_prior)  # with the AxisNet of pool_succ_occ_recipe_s0 (waited for)
      local b j; split_job
      success_labels "$b" || return 1
      AXIS_JOB=pool_succ_occ_recipe_s0 prior pool_succ_prior "$b" "Canonical prior, failed cells 0, whole training pool" ;;
    # trained on views and their mirror images (configs/experiments/recipe/mirror.yaml; docs/results.md)
    mirror_recipe_s[0-9]|styles_mirror_recipe_s[0-9])
      local b j; split_job
      curriculum "$j" "$b" "${j#mirror_recipe_s}" "zoo recipe, mirrored views" --extra-config "$RECIPE" \
        --extra-config configs/experiments/recipe/mirror.yaml ;;
    mirror_prior) prior mirror_prior layouts "Canonical prior, mirrored views" ;;
    # the decoder also reads the base footprint's occupancy from the view (configs/experiments/recipe/occupancy.yaml)
    occ_recipe_s[0-9]|styles_occ_recipe_s[0-9])
      local b j; split_job
      curriculum "$j" "$b" "${j#occ_recipe_s}" "zoo recipe, footprint occupancy input" --extra-config "$RECIPE" \
        --extra-config configs/experiments/recipe/occupancy.yaml ;;
    rank_occ_recipe_s[0-9]|styles_rank_occ_recipe_s[0-9])
      # the best configuration plus a listwise ranking term in the loss (configs/experiments/recipe/rank.yaml)
      local b j; split_job
      curriculum "$j" "$b" "${j#rank_occ_recipe_s}" "occupancy recipe, listwise ranking term" --extra-config "$RECIPE" \
        --extra-config configs/experiments/recipe/occupancy.yaml --extra-config configs/experiments/recipe/rank.yaml ;;
    occ_recipe_rs[0-9]*_s[0-9]|styles_occ_recipe_rs[0-9]*_s[0-9])
      # the best configuration (job occ_recipe_s<seed> first) tested again with its learned residual logit scaled
      # (residual_scale, no training): occ_recipe_rs2_s0 = scale 2, the scale the leave-one-layout-out folds chose
      local b j ckpt scale seed; split_job
      seed=${j##*_s} scale=${j#occ_recipe_rs}; scale=${scale%_s*}
      ckpt=$(stage_ckpt "$RUNS/$b/occ_recipe_s$seed" -1)
      test_run "$(dirname "$(dirname "$ckpt")")" "zoo recipe, footprint occupancy input, residual x$scale" "$b" "$j" \
        "$ckpt" --model.init_args.residual_scale "$scale" ;;
    cv[0-4]_occ|cv[0-4]_rank|cv[0-4]_last|cv[0-4]_succ|cv[0-4]_cov|cv[0-4]_cos|styles_cv[0-4]_occ|styles_cv[0-4]_rank|\
    styles_cv[0-4]_last|styles_cv[0-4]_succ|styles_cv[0-4]_cov|styles_cv[0-4]_cos)
      # leave-one-layout-out validation, fold f = the train scenes of layout f held out for every task (CV_SEED): the
      # best configuration, or it plus the listwise ranking term (rank) or trained on labels with failed cells set
      # to 0 (succ), or that with the footprint coverage input as well (cov) or a per-step cosine schedule in every
      # CFAR stage (cos); trained, then scored on the fold's
      # validation scenes (no test). cv<f>_last trains the best configuration again (with last.ckpt the newest
      # state) and scores its chosen checkpoint (occ2) and its last one (last2)
      local b j f extra=() ck; split_job
      f=${j:2:1}
      [ "${j#*_}" = rank ] && extra=(--extra-config configs/experiments/recipe/rank.yaml)
      if [ "${j#*_}" = succ ] || [ "${j#*_}" = cov ] || [ "${j#*_}" = cos ]; then
        success_labels "$b" || return 1; extra=(--extra-config "configs/experiments/recipe/success_labels_$b.yaml")
      fi
      [ "${j#*_}" = cov ] && extra+=(--extra-config configs/experiments/recipe/coverage.yaml)
      [ "${j#*_}" = cos ] && extra+=(--extra-config configs/experiments/recipe/cosine.yaml)
      if [ "$RETEST" = 0 ]; then
        "$FZ" curriculum --config "configs/experiments/pfal_${PRESET}_$b.yaml" --root "$RUNS/$b/$j" --set "seed_everything=$CV_SEED" \
          --set "data.init_args.val_layout=$f" "${ROOT_SET[@]}" --extra-config "$RECIPE" \
          --extra-config configs/experiments/recipe/occupancy.yaml "${extra[@]}"
      fi
      ck=$(stage_ckpt "$RUNS/$b/$j" -1)
      if [ "${j#*_}" = last ]; then cv_score "$j" "$b" "$f" "occ2=$ck" "last2=$(dirname "$ck")/last.ckpt"
      else cv_score "$j" "$b" "$f" "${j#*_}=$ck"; fi ;;
    cv[0-4]_prior|cv[0-4]_sprior|styles_cv[0-4]_prior|styles_cv[0-4]_sprior)
      # the fold's canonical prior, with the fold's AxisNet (job cv<f>_occ first: this one waits for it); sprior
      # fills it from the labels with failed cells set to 0
      local b j f axis fit=(); split_job
      f=${j:2:1}
      if [ "${j#*_}" = sprior ]; then
        success_labels "$b" || return 1; fit=(--config "configs/experiments/recipe/success_labels_$b.yaml")
      fi
      axis=$(wait_axisnet "$RUNS/$b/cv${f}_occ" "$job") || return 1
      if [ "$RETEST" = 0 ] && [ -z "$(find "$RUNS/$b/$j" -name last.ckpt 2>/dev/null)" ]; then
        "$FZ" fit --config "configs/data/floaff_${PRESET}_$b.yaml" --config configs/models/canonical_prior.yaml \
          --model.init_args.axisnet "$axis" --data.init_args.train_transforms '[]' --trainer.max_epochs 1 \
          --data.init_args.val_layout "$f" --trainer.default_root_dir "$RUNS/$b/$j" "${ROOT_ARGS[@]}" "${fit[@]}"
      fi
      cv_score "$j" "$b" "$f" "${j#*_}=$(latest_run "$RUNS/$b/$j")/checkpoints/last.ckpt" ;;
    occ_cfar_pfal_s[0-9]|styles_occ_cfar_pfal_s[0-9])  # the same input on the paper's path (no recipe departures)
      local b j; split_job
      curriculum "$j" "$b" "${j#occ_cfar_pfal_s}" "CFAR+PFAL, footprint occupancy input" \
        --extra-config configs/experiments/recipe/occupancy.yaml ;;
    pool_pointnet2_s[0-9]|pool_navaff_s[0-9]|pool_votenet_s[0-9]|pool_h3dnet_s[0-9]|pool_n2m_s[0-9]|\
    styles_pool_pointnet2_s[0-9]|styles_pool_navaff_s[0-9]|styles_pool_votenet_s[0-9]|styles_pool_h3dnet_s[0-9]|\
    styles_pool_n2m_s[0-9])
      # every learned baseline on the whole training pool too (pool_<model>_s<seed>; the benchmark's labels, as the
      # paper trains them)
      local b j m; split_job
      m=${j#pool_}; m=${m%_s*}
      baseline "$j" "$b" "${j##*_s}" "configs/demo/${m}_demo.yaml" "$(label_of "$m"), whole training pool" \
        --data.init_args.val_scenes 0 ;;
    pool_cfar_pfal_s[0-9]|styles_pool_cfar_pfal_s[0-9])  # the paper's path (no zoo departures) on the whole pool
      local b j; split_job
      curriculum "$j" "$b" "${j#pool_cfar_pfal_s}" "CFAR+PFAL, whole training pool" --set data.init_args.val_scenes=0 ;;
    occ_pointnet2_s[0-9]|styles_occ_pointnet2_s[0-9])  # the same input for PointNet++ (a fairness check)
      local b j; split_job
      baseline "$j" "$b" "${j#occ_pointnet2_s}" configs/demo/pointnet2_demo.yaml "PointNet++, footprint occupancy input" \
        --config configs/experiments/recipe/occupancy.yaml ;;
    styles_mirror_prior) prior mirror_prior styles "Canonical prior, mirrored views" ;;
    styles_fresh_prior) prior fresh_prior styles "Canonical prior, repeated-episode labels" ;;
    # the prior's cell edges on the label lattice, as before the grid centred its cells (docs/method.md)
    prior_edges) prior prior_edges layouts "Canonical prior, edge-binned" ;;
    styles_prior_edges) prior prior_edges styles "Canonical prior, edge-binned" ;;
    recipe_edges_s[0-9]) curriculum "$job" layouts "${job#recipe_edges_s}" "zoo recipe, edge-binned prior" \
      --extra-config "$RECIPE" --extra-config configs/experiments/recipe/prior_edges.yaml ;;
    styles_recipe_edges_s[0-9]) curriculum "${job#styles_}" styles "${job#styles_recipe_edges_s}" \
      "zoo recipe, edge-binned prior" --extra-config "$RECIPE" --extra-config configs/experiments/recipe/prior_edges.yaml ;;
    no_crop|no_align|no_sdl|no_fd)
      curriculum "$job" layouts 0 "w/o ${job#no_}" --extra-config "configs/experiments/ablations/$job.yaml" ;;
    r1.[0-9]*)
      # the sweep file sets CFAR's crop radius only (not AxisNet's); the curriculum's --root beats its
      # default_root_dir
      curriculum "sweep_$job" layouts 0 "r=${job#r}" --extra-config "configs/experiments/sweep_crop/$job.yaml" ;;
    gtyaw_s[0-9]) # the final model with the simulator's target yaw instead of AxisNet's (upper bound of Align)
      stage_test "$job" "cfar_pfal_s${job#gtyaw_s}" -1 "CFAR+PFAL, simulator yaw" --model.init_args.eval_yaw_source gt ;;
    axisnet_longer) axisnet_longer ;;
    axis100_s[0-9]) # the final model with the longer-trained AxisNet (job axisnet_longer first)
      local axis; axis=$(find "$RUNS/layouts/axisnet100" -name 'epoch*.ckpt' 2>/dev/null | head -n 1)
      [ -n "$axis" ] || { echo "$job: no AxisNet under $RUNS/layouts/axisnet100; run the job axisnet_longer first" >&2; return 1; }
      stage_test "$job" "cfar_pfal_s${job#axis100_s}" -1 "CFAR+PFAL, AxisNet 100 epochs" --model.init_args.axisnet "$axis" ;;
    stage1_s[0-9]) # PFAL stage 1 alone (trained on PnPCounterToCab only), tested on all four tasks
      stage_test "$job" "cfar_pfal_s${job#stage1_s}" 1 "CFAR, stage 1 only" ;;
    st_*|styles_st_*) single_task ;;  # one model per task (the paper's Table 3)
    styles_cfar_pfal) curriculum cfar_pfal_s0 styles 0 "CFAR+PFAL" ;;
    styles_pointnet2) baseline pointnet2_s0 styles 0 configs/demo/pointnet2_demo.yaml "PointNet++" ;;
    styles_c2f_exp) training_free c2f_exp styles C2F-Exp ;;
    *) echo "unknown job '$job'; jobs: ${JOBS[*]}" >&2; return 2 ;;
  esac
}

job_out() {  # the file a finished job has written, under $OUT
  case $1 in
    axisnet_longer) echo layouts/axisnet_yaw_error.md ;;
    styles_c2f_exp) echo styles/c2f_exp/report.json ;;
    styles_prior) echo styles/prior/report.json ;;
    styles_prior_edges) echo styles/prior_edges/report.json ;;
    styles_fresh_prior) echo styles/fresh_prior/report.json ;;
    styles_succ_prior) echo styles/succ_prior/report.json ;;
    styles_pool_succ_prior) echo styles/pool_succ_prior/report.json ;;
    styles_mirror_prior) echo styles/mirror_prior/report.json ;;
    styles_recipe_s*) echo "styles/recipe_s${1#styles_recipe_s}/report.json" ;;
    styles_recipe_no_*|styles_occ_recipe_no_*|styles_pool_succ_occ_recipe_no_*) echo "styles/${1#styles_}/report.json" ;;
    styles_recipe_r1.*|styles_occ_recipe_r1.*|styles_pool_succ_occ_recipe_r1.*)
      local j=${1#styles_}; echo "styles/${j/recipe_r/recipe_sweep_r}/report.json" ;;
    recipe_r1.*|occ_recipe_r1.*|pool_succ_occ_recipe_r1.*) echo "layouts/${1/recipe_r/recipe_sweep_r}/report.json" ;;
    styles_cv[0-4]_*) echo "cv/styles/${1#styles_}.json" ;;
    cv[0-4]_*) echo "cv/layouts/$1.json" ;;
    styles_*_s[0-9]) echo "styles/${1#styles_}/report.json" ;;
    styles_*) echo "styles/${1#styles_}_s0/report.json" ;;
    r1.*) echo "layouts/sweep_$1/report.json" ;;
    *) echo "layouts/$1/report.json" ;;
  esac
}

if [ "${1:-}" = "--one" ]; then
  shift
  job=$1
  if [ "${RETEST:-0}" = 0 ] && [ -f "$OUT/$(job_out "$job")" ]; then echo "[$job] report exists, skipped"; exit 0; fi
  mkdir -p "$RUNS/logs"
  t0=$(date +%s)
  if OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} run_job "$job" > "$RUNS/logs/$job.log" 2>&1; then
    echo "[$job] done in $(( $(date +%s) - t0 )) s"
  else
    echo "[$job] FAILED after $(( $(date +%s) - t0 )) s, see $RUNS/logs/$job.log"
    exit 1
  fi
  exit 0
fi

[ $# -gt 0 ] && JOBS=("$@")
[ "$PAR" -gt 1 ] || export OMP_NUM_THREADS=${OMP_NUM_THREADS:-2}
printf '%s\n' "${JOBS[@]}" | xargs -P "$PAR" -I{} "$SELF" --one {}
exit
}
