#!/usr/bin/env bash
# The GPU speeds of docs/bench/ on this machine's accelerator, one JSON file each in OUT:
# the laptop network's BC and BC-RL update (6 settings x 3 seeds), the gpu profile's (the same
# at 12 seeds) and the paper network's at the paper's batch (256 scenarios x 3 seeds), BC also
# traced (its busiest kernels). Each file records the machine, the date and the matrix TFLOP/s
# (docs/bench/README.md says how they are counted); igdrivsim/training/cost.py takes its GPU
# rates from the gpu and paper files.
#
#   bash scripts/bench_gpu.sh OUT        # e.g. OUT=docs/bench; a few minutes on one H100
set -euo pipefail
for arg in "$@"; do
    if [ "$arg" = "--help" ] || [ "$arg" = "-h" ]; then
        cat <<'EOF'
usage: bash scripts/bench_gpu.sh OUT

The GPU speeds of docs/bench/ on this machine's accelerator, seven JSON files in OUT named by
the device (TAG, e.g. h100): train_laptop_bc_TAG and train_laptop_bc_rl_TAG (the laptop
network, 6 settings x 3 seeds, 5 updates), train_gpu_bc_TAG and train_gpu_bc_rl_TAG (the gpu
profile: the same at 12 seeds), train_paper_bc_TAG and train_paper_bc_rl_TAG (the paper network
at 256 scenarios x 3 seeds, 2 updates) and train_paper_bc_trace_TAG (one more update traced
into OUT/trace_TAG).

  OUT     the folder to write, e.g. docs/bench (required)
  PYTHON  environment variable: the Python with igdrivsim and JAX for the GPU (default: python3)
  -h, --help  print this help and exit (runs nothing)

Exits 2 without writing anything when JAX finds no accelerator.
EOF
        exit 0
    fi
done
OUT="${1:?usage: bash scripts/bench_gpu.sh OUT}"
PYTHON="${PYTHON:-python3}"
if [ "$("$PYTHON" -c 'import jax; print(jax.default_backend())')" = cpu ]; then
    echo "bench_gpu.sh: no accelerator found (jax.default_backend() is cpu); the paper" \
         "network's update takes minutes per update on a CPU" >&2
    exit 2
fi
mkdir -p "$OUT"
tag="$("$PYTHON" -c 'import jax; print(jax.devices()[0].device_kind.split()[-1].lower())')"
B=("$PYTHON" -m igdrivsim.cli bench train)
for m in bc bc_rl; do
    "${B[@]}" --profiles laptop --method $m --updates 5 --out "$OUT/train_laptop_${m}_$tag.json"
    "${B[@]}" --profiles gpu --method $m --updates 5 --out "$OUT/train_gpu_${m}_$tag.json"
done
P=(--profiles paper --obs full --batch-size 256 --seeds 3 --updates 2)
"${B[@]}" "${P[@]}" --method bc --out "$OUT/train_paper_bc_$tag.json"
"${B[@]}" "${P[@]}" --method bc_rl --out "$OUT/train_paper_bc_rl_$tag.json"
"${B[@]}" "${P[@]}" --method bc --updates 1 --trace "$OUT/trace_$tag" \
    --out "$OUT/train_paper_bc_trace_$tag.json"
