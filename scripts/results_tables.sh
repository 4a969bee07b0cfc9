#!/usr/bin/env bash
# The tables and pictures of docs/results.md from the committed report.json files:
#   scripts/results_tables.sh > /tmp/tables.md      (pictures need the runs/ of scripts/reproduce_small.sh)
#   OUT=docs/results/dense RUNS=runs/dense scripts/results_tables.sh   # the dense preset's protocol
#   OUT=docs/results/split BASE=docs/results/topup scripts/results_tables.sh   # main rows missing from OUT from BASE
set -euo pipefail
SELF=$(realpath "$0")
cd "$(dirname "$SELF")/.."
if ! command -v floaff-zoo > /dev/null && [ -x .venv/bin/floaff-zoo ]; then PATH=$PWD/.venv/bin:$PATH; fi
R=${OUT:-docs/results/small_v2}

if [ -n "${BASE:-}" ] && [ ! -d "$BASE" ]; then echo "results_tables.sh: BASE=$BASE is not a directory" >&2; exit 2; fi
MAIN=()   # the method (its variants too) and every baseline, both benchmarks (rows: the report's label, seeds pooled)
declare -A SEEN  # BASE=<another OUT>: a job missing from $R is read from there (runs a change did not touch)
for root in "$R" ${BASE:+"$BASE"}; do
  for d in "$root"/layouts/{recipe_s?,occ_recipe_s?,cfar_pfal_s?,prior,prior_gtyaw,pointnet2_s?,navaff,votenet,h3dnet,n2m} \
           "$root"/layouts/{navaff_s?,votenet_s?,h3dnet_s?,n2m_s?,c2f_exp,c2f_exp_gtyaw} \
           "$root"/styles/{recipe_s?,occ_recipe_s?,cfar_pfal_s?,prior,pointnet2_s?,navaff_s?,votenet_s?,h3dnet_s?,n2m_s?,c2f_exp}; do
    job=${d#"$root"/}
    if [ -f "$d/report.json" ] && [ -z "${SEEN[$job]:-}" ]; then MAIN+=("$d"); SEEN[$job]=1; fi
  done
done
table() { floaff-zoo table --format md --group-by label "$@"; echo; }
# variant_tables RUN...: map metrics, SR by view and SR by task of runs pooled per label (ablations, variants)
variant_tables() {
  table --runs "$@" --preset ablation
  table --runs "$@" --preset sr_views --no-oracle
  table --runs "$@" --preset sr_tasks --no-oracle
}

echo "### Map metrics (analogue of Table 1)"; echo
table --runs "${MAIN[@]}" --preset map
echo "### Multi-task success rate by view (analogue of Table 2)"; echo
table --runs "${MAIN[@]}" --preset sr_views
echo "### Success rate by task (analogue of Table 3)"; echo
table --runs "${MAIN[@]}" --preset sr_tasks

ABL=("$R"/layouts/cfar_pfal_s0)
for d in "$R"/layouts/no_{crop,align,sdl,fd}; do [ -f "$d/report.json" ] && ABL+=("$d"); done
if [ ${#ABL[@]} -gt 1 ]; then
  echo "### Ablations on Layouts (analogue of Tables 4-5; seed 0 each)"; echo
  table --runs "${ABL[@]}" --preset ablation
  table --runs "${ABL[@]}" --preset sr_views --no-oracle
fi

for bench in layouts styles; do  # the ablations and the crop sweep on top of the zoo recipe (dense protocol)
  name=Layouts; [ $bench = styles ] && name=Styles
  ABLR=()  # the recipe's seeds and every seed of each ablation (rows pool the runs of one label)
  for d in "$R/$bench"/recipe_s? "$R/$bench"/recipe_no_{crop,align,sdl,fd}{,_s?}; do
    [ -f "$d/report.json" ] && ABLR+=("$d")
  done
  if [ -f "$R/$bench/recipe_no_crop/report.json" ]; then
    echo "### Ablations of the zoo recipe on $name (analogue of Tables 4-5; seeds pooled per row)"; echo
    variant_tables "${ABLR[@]}"
  fi
  OCC=()  # the footprint-occupancy input on CFAR (tested after its validation decision) and PointNet++ (fairness check)
  for d in "$R/$bench"/{recipe_s?,occ_recipe_s?,cfar_pfal_s?,occ_cfar_pfal_s?,pointnet2_s?,occ_pointnet2_s?,prior}; do
    [ -f "$d/report.json" ] && OCC+=("$d")
  done
  if [ -f "$R/$bench/occ_recipe_s0/report.json" ]; then
    echo "### Footprint occupancy as an input on $name (test split, a diagnostic; seeds pooled per row)"; echo
    variant_tables "${OCC[@]}"
  fi
  # the crop sweep of the zoo recipe and (occ_) of the best configuration, recipe + footprint occupancy input:
  # rows pool the seeds of one radius; the own radius takes as many seeds of the configuration as the sweep has
  for pre in "" occ_; do
    what="the zoo recipe"; [ -n "$pre" ] && what="the best configuration (recipe + footprint occupancy input)"
    SWR=("$R/$bench/${pre}recipe_s0")
    for d in "$R/$bench/${pre}"recipe_sweep_r*; do [ -f "$d/report.json" ] && SWR+=("$d"); done
    for s in 1 2; do
      if compgen -G "$R/$bench/${pre}recipe_sweep_r*_s$s/report.json" > /dev/null \
        && [ -f "$R/$bench/${pre}recipe_s$s/report.json" ]; then
        SWR+=("$R/$bench/${pre}recipe_s$s")
      fi
    done
    if [ ${#SWR[@]} -gt 1 ]; then
      echo "### Crop-radius sweep of $what on $name (seeds pooled per radius)"; echo
      floaff-zoo table --format md --runs "${SWR[@]}" --preset sweep; echo
      table --runs "${SWR[@]}" --preset sr_views --no-oracle
    fi
  done
done

SWEEP=("$R"/layouts/cfar_pfal_s0)
for d in "$R"/layouts/sweep_r*; do [ -f "$d/report.json" ] && SWEEP+=("$d"); done
REC=("$R"/layouts/recipe_s0)
NO_FD=no_fd; [ -f "$R/layouts/recipe_no_crop/report.json" ] && NO_FD=""  # then in the recipe's ablation table
for d in "$R"/layouts/recipe_{no_prior,no_snap,pointwise,$NO_FD} "$R"/layouts/cfar_pfal_s0; do [ -f "$d/report.json" ] && REC+=("$d"); done
if [ ${#REC[@]} -gt 1 ]; then  # the recipe alone is no comparison
  echo "### The zoo recipe's switches on Layouts (seed 0 each)"; echo
  table --runs "${REC[@]}" --preset ablation
  table --runs "${REC[@]}" --preset sr_views --no-oracle
fi

if [ ${#SWEEP[@]} -gt 1 ]; then
  echo "### Crop-radius sweep on Layouts (seed 0 each)"; echo
  floaff-zoo table --format md --runs "${SWEEP[@]}" --preset sweep; echo
fi

DIAG=()
for d in "$R"/layouts/{gtyaw_s?,axis100_s?,stage1_s?}; do [ -f "$d/report.json" ] && DIAG+=("$d"); done
if [ ${#DIAG[@]} -gt 0 ]; then
  for d in "$R"/layouts/cfar_pfal_s?; do [ -f "$d/report.json" ] && DIAG+=("$d"); done
  echo "### Diagnostics: where the target yaw comes from, and PFAL stage 1 alone (Layouts, 3 seeds)"; echo
  [ -f "$R/layouts/axisnet_yaw_error.md" ] && { echo "AxisNet test angle error per task:"; echo; cat "$R/layouts/axisnet_yaw_error.md"; echo; }
  table --runs "${DIAG[@]}" --preset map
  table --runs "${DIAG[@]}" --preset sr_views --no-oracle
  table --runs "${DIAG[@]}" --preset sr_tasks --no-oracle
fi

if [ -d "${RUNS:-runs/small_v2}" ]; then  # pictures like the paper's Figures 4 and 6 (need the runs' figures on disk)
  for bench in layouts styles; do
    cols=()
    for d in "$R/$bench"/{recipe_s0,cfar_pfal_s0,prior,pointnet2_s0,c2f_exp}; do [ -f "$d/report.json" ] && cols+=("$d"); done
    floaff-zoo montage --runs "${cols[@]}" --cases CloseDrawer_front_0 CloseDrawer_side_0 OpenSingleDoor_front_0 \
      OpenSingleDoor_side_0 --out "$R/fig4_$bench.png" >&2 || echo "fig4_$bench not drawn" >&2
    floaff-zoo montage --runs "${cols[@]}" --cases PnPCounterToCab_front_0 PnPCounterToCab_side_0 \
      CloseDoubleDoor_front_0 CloseDoubleDoor_side_0 --out "$R/fig6_$bench.png" >&2 || echo "fig6_$bench not drawn" >&2
  done
fi
