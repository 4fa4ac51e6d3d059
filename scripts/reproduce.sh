#!/usr/bin/env bash
# Regenerate the report's tables and figures from a fresh clone.
#
# usage: bash scripts/reproduce.sh [--profile smoke|quick|laptop|gpu|paper] [--data DIR | --data TRAIN VAL]
#                                  [--out DIR] [--obs a,b] [--methods a,b] [--set SECTION.FIELD=VALUE ...]
#                                  [--samples DIR ...] [--workers N] [--in-process] [--no-progress] [--help]
# Defaults: --profile laptop, synthetic data, --out outputs/<profile>/ (report in paper/), the
# paper's six settings, --methods bc_rl,bc, --workers 0 (one per CPU core).
# Stages: data (synthetic, unless --data) -> filter -> train -> evaluate -> speed walk -> maze
# -> render Fig. 1 -> report (tables, figures, docs/results.md) -> real logs -> PDF (if latexmk).
# --samples DIR ...: real scenarios besides the samples cache (igdrivsim samples fetches the public
# WOMD ones) for Fig. 1 and the real-log table; without any both are skipped/synthetic.
# Resumable: rerun the same command after an interruption; complete stages are skipped.
# Logs: <work>/logs/<stage>.log (work = outputs/<profile>/, or --out).
# Python: $PYTHON, else the active virtual environment's, else python3 on PATH. When igdrivsim
# is not importable there, it is installed into that environment first (pip install -e .);
# --help prints and exits without installing anything.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO"
if [ -z "${PYTHON:-}" ] && [ -n "${VIRTUAL_ENV:-}" ] && [ -x "$VIRTUAL_ENV/bin/python" ]; then
    PYTHON="$VIRTUAL_ENV/bin/python"
fi
PYTHON="${PYTHON:-python3}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python

importable() { "$PYTHON" -c "import igdrivsim.pipeline.cli" >/dev/null 2>&1; }

for arg in "$@"; do
    if [ "$arg" = "--help" ] || [ "$arg" = "-h" ]; then
        if importable; then
            exec "$PYTHON" -m igdrivsim.pipeline --help
        fi
        sed -n '2,17p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
        echo "(igdrivsim is not installed for $PYTHON; the first run installs it)"
        exit 0
    fi
done

if ! importable; then
    PREFIX="$("$PYTHON" -c 'import sys; print(sys.prefix)')"
    echo "[reproduce] setup: igdrivsim is not importable by $PYTHON; installing it and its" \
         "dependencies into $PREFIX (pip install -e $REPO; set PYTHON or activate a" \
         "virtual environment to install elsewhere)" >&2
    "$PYTHON" -m pip install -e "$REPO" || {
        echo "[reproduce] setup failed: could not pip install -e $REPO into $PREFIX" >&2
        exit 1
    }
fi

export PYTHONUNBUFFERED=1
exec "$PYTHON" -m igdrivsim.pipeline "$@"
