#!/usr/bin/env bash
# Regenerate every figure and table of the report from a fresh clone.
#
#   bash scripts/reproduce.sh [--profile smoke|laptop|gpu|paper] [--data DIR | --data TRAIN VAL]
#                             [--out DIR] [--obs a,b] [--no-progress]
#
# Stages: data (synthetic, unless --data) -> filter -> train (6 settings x {BC, BC-RL} x seeds)
# -> evaluate -> maze study -> render Fig. 1 -> report (Table I, Fig. 3) -> PDF (if latexmk).
# Resumable: rerun the same command after an interruption; complete stages are skipped.
# Logs: <work>/logs/<stage>.log (work = outputs/<profile>/, or --out).
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"
PYTHON="${PYTHON:-python3}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python

if ! "$PYTHON" -c "import igdrivsim.evaluation.pipeline" >/dev/null 2>&1; then
    echo "[reproduce] setup: igdrivsim is not importable, running: pip install -e ." >&2
    "$PYTHON" -m pip install -e "$REPO" || {
        echo "[reproduce] setup failed: could not pip install -e $REPO" >&2
        exit 1
    }
fi

export PYTHONUNBUFFERED=1
exec "$PYTHON" -m igdrivsim.evaluation.pipeline "$@"
