#!/usr/bin/env bash
# PFAL retention: PnPCounterToCab on the validation scene after stage 1 and after stage 2 of a curriculum.
#   scripts/pfal_retention.sh runs/small_v2/layouts/recipe_s0 [more curriculum roots ...]
# Prints one Markdown row per root: val PCC / SIM of both stages' best checkpoints and the change.
set -euo pipefail
cd "$(dirname "$(realpath "$0")")/.."
if ! command -v floaff-zoo > /dev/null && [ -x .venv/bin/floaff-zoo ]; then PATH=$PWD/.venv/bin:$PATH; fi
echo "| run | stage 1 PCC / SIM | stage 2 PCC / SIM | change in PCC |"
echo "|---|---:|---:|---:|"
for root in "$@"; do
  row="| $(basename "$root") |"
  pccs=()
  for idx in -2 -1; do
    # a curriculum killed in its last stage leaves the earlier ones, marked "complete": false (read_lineage): their
    # last two are not stage 1 and stage 2 (the small recipe's are its AxisNet stage and stage 1)
    ckpt=$(python3 -c "
import json, sys
lineage = json.load(open(sys.argv[1]))
if lineage.get('complete') is False:
    sys.exit(f'pfal_retention.sh: {sys.argv[1]}: the curriculum did not finish; run it again to finish it')
print(lineage['stages'][int(sys.argv[2])]['checkpoint'])" "$root/lineage.json" "$idx")
    out=$(floaff-zoo validate --config "$(dirname "$(dirname "$ckpt")")/config.yaml" --ckpt_path "$ckpt" \
      --data.init_args.tasks '[PnPCounterToCab]' --trainer.enable_progress_bar false \
      --trainer.logger.init_args.save_dir "$root/retention" 2>/dev/null)
    pcc=$(echo "$out" | awk '/val_pcc / {print $2}'); sim=$(echo "$out" | awk '/val_sim / {print $2}')
    pccs+=("$pcc")
    row="$row $(printf '%.3f / %.3f' "$pcc" "$sim") |"
  done
  echo "$row $(python3 -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):+.3f}')" "${pccs[@]}") |"
done
