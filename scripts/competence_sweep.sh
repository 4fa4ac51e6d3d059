#!/usr/bin/env bash
# Full BC of a profile under training variants, on a reproduce.sh run's data: each variant
# trained (3 seeds, closed-loop validation on every validation scenario at each checkpoint) and
# evaluated as the pipeline does, then one table (igdrivsim report sweep) in
# WORK/sweep.md. Variants run side by side (JOBS at a time); on a GPU all of them at once.
#
#   bash scripts/competence_sweep.sh WORK NAME[=SECTION.FIELD=VALUE,...] ...
#   e.g. bash scripts/competence_sweep.sh /tmp/sweep base b32=data.batch_size=32 \
#            lr6e-3=training.lr=6e-3 b32e1=data.batch_size=32,training.ppo_epochs=1
#
# RUN (default outputs/PROFILE, the default run's work folder; PROFILE default laptop) is the
# reproduce.sh --out folder whose filtered data, teacher cache and reference evaluation are used.
set -uo pipefail
for arg in "$@"; do
    if [ "$arg" = "--help" ] || [ "$arg" = "-h" ]; then
        cat <<'EOF'
usage: bash scripts/competence_sweep.sh WORK NAME[=SECTION.FIELD=VALUE,...] ...

Full BC under training variants on a reproduce.sh run's data: each variant trained (3 seeds,
closed-loop validation at every checkpoint) and evaluated as the pipeline does, then one table
(igdrivsim report sweep) in WORK/sweep.md. For example:
  bash scripts/competence_sweep.sh /tmp/sweep base b32=data.batch_size=32 lr6e-3=training.lr=6e-3

  WORK     the sweep's folder: runs/NAME, evals/NAME, logs/, sweep.md (required)
  NAME     a variant: its name, then = and its config overrides, comma-separated (at least
           one; a bare name trains the profile unchanged)
Environment variables:
  PROFILE  the training profile (default: laptop)
  RUN      the reproduce.sh --out folder whose filtered data, teacher cache and reference
           evaluation are used (default: outputs/PROFILE in this repository)
  JOBS     variants trained side by side (default: the number of CPUs, nproc)
  PYTHON   the Python with igdrivsim (default: python3)
  -h, --help  print this help and exit (runs nothing)
EOF
        exit 0
    fi
done
WORK="${1:?usage: bash scripts/competence_sweep.sh WORK NAME[=OVERRIDES] ...}"; shift
[ $# -gt 0 ] || { echo "competence_sweep.sh: name at least one variant (e.g. base)" >&2; exit 2; }
PROFILE="${PROFILE:-laptop}"; JOBS="${JOBS:-$(nproc)}"
RUN="${RUN:-$(cd "$(dirname "$0")/.." && pwd)/outputs/$PROFILE}"
PYTHON="${PYTHON:-python3}"; I=("$PYTHON" -m igdrivsim.cli)
for need in filtered/training/manifest.jsonl filtered/validation/counts.json \
            evals/references/per_scenario.csv; do
    [ -f "$RUN/$need" ] || { echo "competence_sweep.sh: $RUN/$need not found: run" \
        "bash scripts/reproduce.sh --profile $PROFILE first (or set RUN to its --out folder)" >&2
        exit 2; }
done
mkdir -p "$WORK/logs"
VAL=$("$PYTHON" -c "import json, sys; print(json.load(open(sys.argv[1]))['kept'])" \
      "$RUN/filtered/validation/counts.json") || exit 1
variant() {  # NAME[=OVERRIDES]
    local name="${1%%=*}" sets=(--set training.eval_every=250 --set training.val_scenarios=$VAL
                                --set training.checkpoint_every=250 --set training.log_every=50)
    [ "$name" != "$1" ] && IFS=, read -ra extra <<< "${1#*=}" && for s in "${extra[@]}"; do
        sets+=(--set "$s"); done
    local t=$SECONDS
    echo "$name: training (progress, rate and ETA: $WORK/logs/train_$name.log)"
    "${I[@]}" train --profile "$PROFILE" --obs full --method bc --seeds 3 --resume \
        --data "$RUN/filtered/training" --val-data "$RUN/filtered/validation" \
        --cache-dir "$RUN/cache" --out "$WORK/runs/$name" "${sets[@]}" \
        > "$WORK/logs/train_$name.log" 2>&1 || echo "$name: training failed ($WORK/logs/train_$name.log)"
    "${I[@]}" evaluate "$WORK/runs/$name" --out "$WORK/evals/$name" --no-progress \
        --data "$RUN/filtered/validation" --batch-size 32 --limit 0 > "$WORK/logs/eval_$name.log" 2>&1
    echo "$name: trained and evaluated in $((SECONDS - t)) s"
}
for v in "$@"; do
    while [ "$(jobs -rp | wc -l)" -ge "$JOBS" ]; do wait -n; done
    variant "$v" &
done
wait
"${I[@]}" report sweep "$WORK" --references "$RUN/evals/references" \
    --out "$WORK/sweep.md"
