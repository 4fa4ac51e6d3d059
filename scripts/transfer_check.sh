#!/usr/bin/env bash
# Does a synthetic motion model teach drivers that hold up on real logs? Generates the laptop
# profile's synthetic data (3,072 training / 512 validation scenarios, seed 0) with MOTION,
# filters it, trains Full BC (laptop profile, 3 seeds, 1,000 updates) and evaluates it and the
# reference actors on the synthetic validation set and on each real set (every vehicle that
# passes the scenario filter as the ego in turn), and under the greedy and mean action read-outs
# on every real set at once (WORK/MOTION/real_logs/tables/real_logs.md); then
# igdrivsim report transfer compares every WORK/MOTION folder in WORK/transfer.md.
#
#   bash scripts/transfer_check.sh WORK MOTION [NAME=LOCATION ...]
#   e.g. bash scripts/transfer_check.sh /tmp/transfer calibrated
set -euo pipefail
for arg in "$@"; do
    if [ "$arg" = "--help" ] || [ "$arg" = "-h" ]; then
        cat <<'HELP'
usage: bash scripts/transfer_check.sh WORK MOTION [NAME=LOCATION ...]

Full BC (laptop profile, 3 seeds) trained on synthetic data generated with MOTION, evaluated
with the reference actors on its synthetic validation set and on real logs; then one table
comparing every motion run so far under WORK (WORK/transfer.md, igdrivsim report transfer).
Resumable: rerun the same command after an interruption.

  WORK           the check's folder: WORK/MOTION/{data,filtered,cache,runs,evals_*} (required)
  MOTION         the generator's motion model: default or calibrated (required)
  NAME=LOCATION  real sets (default: womd_samples=the igdrivsim samples cache,
                 nuscenes=../shared/data/scenarionet/sd_nuscenes*.pkl,
                 womd_scenario=../shared/data/scenarionet/sd_waymo*.pkl and
                 gpudrive=../shared/data/gpudrive when present); every vehicle that
                 passes the scenario filter is the ego in turn on each
Environment variables:
  PYTHON   the Python with igdrivsim (default: python3)
  -h, --help  print this help and exit (runs nothing)
HELP
        exit 0
    fi
done
WORK="${1:?usage: bash scripts/transfer_check.sh WORK MOTION [NAME=LOCATION ...]}"
MOTION="${2:?usage: bash scripts/transfer_check.sh WORK MOTION [NAME=LOCATION ...]}"; shift 2
PYTHON="${PYTHON:-python3}"; I=("$PYTHON" -m igdrivsim.cli)
REPO="$(cd "$(dirname "$0")/.." && pwd)"; SHARED="$REPO/../shared/data/scenarionet"
GPUDRIVE="$REPO/../shared/data/gpudrive"
REAL=("$@")
if [ ${#REAL[@]} -eq 0 ]; then
    CACHE=$("$PYTHON" -c "from igdrivsim.data import samples; print(samples.find_samples() or '')")
    if [ -n "$CACHE" ]; then REAL+=("womd_samples=$CACHE"); else
        echo "transfer_check.sh: no public WOMD samples (igdrivsim samples fetches them):" \
             "evaluating on the other real sets only" >&2; fi
    compgen -G "$SHARED/sd_nuscenes*.pkl" >/dev/null && REAL+=("nuscenes=$SHARED/sd_nuscenes*.pkl")
    compgen -G "$SHARED/sd_waymo*.pkl" >/dev/null && REAL+=("womd_scenario=$SHARED/sd_waymo*.pkl")
    compgen -G "$GPUDRIVE/*.json" >/dev/null && REAL+=("gpudrive=$GPUDRIVE")
fi
W="$WORK/$MOTION"; mkdir -p "$W/logs"; cd "$W"
[ -f logs/generated ] || { "${I[@]}" generate --motion "$MOTION" --out data --train 3072 \
    --val 512 --seed 0 --no-progress > logs/generate.log && touch logs/generated; }
for split in training validation; do
    [ -f "filtered/$split/manifest.jsonl" ] || "${I[@]}" filter "data/$split" \
        --out "filtered/$split" --no-progress > "logs/filter_$split.log"
done
VAL=$("$PYTHON" -c "import json; print(json.load(open('filtered/validation/counts.json'))['kept'])")
echo "$MOTION: training Full BC (progress, rate and ETA: $W/logs/train.log)"
"${I[@]}" train --profile laptop --obs full --method bc --seeds 3 --resume \
    --data filtered/training --val-data filtered/validation --cache-dir cache --out runs/bc \
    --set training.eval_every=250 --set training.val_scenarios="$VAL" \
    --set training.checkpoint_every=250 > logs/train.log 2>&1
for set in "validation=filtered/validation" "${REAL[@]}"; do
    name="${set%%=*}"; where="${set#*=}"
    for who in bc references; do
        [ -f "evals_$name/$who/per_scenario.csv" ] && continue
        like=(runs/bc); [ "$who" = references ] && like=(--references --like runs/bc)
        egos=sdc; [ "$name" = validation ] || egos=all  # real logs: every vehicle as the ego
        "${I[@]}" evaluate "${like[@]}" --out "evals_$name/$who" --data "$where" \
            --egos "$egos" --batch-size 32 --limit 0 --no-progress >> logs/evaluate.log
    done
done
echo "$MOTION: evaluated on validation and ${#REAL[@]} real set(s)"
if [ ${#REAL[@]} -gt 0 ]; then  # every real set at once, Full BC under each action read-out
    WHERE=(); for set in "${REAL[@]}"; do WHERE+=("${set#*=}"); done
    ALL=(--data "${WHERE[@]}" --egos all --batch-size 32 --limit 0 --no-progress)
    for who in bc references greedy mean; do
        case $who in
            bc) out=real_logs/runs/bc; args=(runs/bc) ;;
            references) out=real_logs/runs/references; args=(--references --like runs/bc) ;;
            *) out="real_logs/readouts/$who"; args=(runs/bc --actions "$who") ;;
        esac
        [ -f "$out/per_scenario.csv" ] || "${I[@]}" evaluate "${args[@]}" --out "$out" \
            "${ALL[@]}" >> logs/evaluate.log
    done
    "${I[@]}" report real-logs --real real_logs/runs --readouts real_logs/readouts \
        --out real_logs/tables --real-label "every real set above" >> logs/evaluate.log
    echo "$MOTION: Full BC's action read-outs on every real set: $W/real_logs/tables/real_logs.md"
fi
"${I[@]}" report transfer "$WORK" --out "$WORK/transfer.md"
