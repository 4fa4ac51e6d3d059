#!/usr/bin/env bash
# The GPU speeds of docs/bench/ on this machine's accelerator, one JSON file each in OUT:
# the laptop network's BC and BC-RL update (6 settings x 3 seeds) and the paper network's BC
# update at the paper's batch (256 scenarios x 3 seeds), with JAX's default matrix precision,
# with bf16 products, traced (its busiest kernels) and with XLA's Triton matrix-product fusions
# off (cuBLAS products). Each file records the machine, the date, the precision and the matrix
# TFLOP/s (docs/bench/README.md says how they are counted).
#
#   bash scripts/bench_gpu.sh OUT        # e.g. OUT=docs/bench; a few minutes on one H200
set -euo pipefail
for arg in "$@"; do
    if [ "$arg" = "--help" ] || [ "$arg" = "-h" ]; then
        cat <<'EOF'
usage: bash scripts/bench_gpu.sh OUT

The GPU speeds of docs/bench/ on this machine's accelerator, six JSON files in OUT named by the
device (TAG, e.g. h200): train_laptop_bc_TAG and train_laptop_bc_rl_TAG (the laptop network, 5
updates), train_paper_bc_TAG (the paper network at 256 scenarios x 3 seeds, 2 updates),
train_paper_bc_bf16_TAG (bf16 products), train_paper_bc_trace_TAG (one more update traced into
OUT/trace_TAG) and train_paper_bc_cublas_TAG (XLA's Triton matrix-product fusions off).

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
"${B[@]}" --profiles laptop --method bc --updates 5 --out "$OUT/train_laptop_bc_$tag.json"
"${B[@]}" --profiles laptop --method bc_rl --updates 5 --out "$OUT/train_laptop_bc_rl_$tag.json"
P=(--profiles paper --method bc --obs full --batch-size 256 --seeds 3 --updates 2)
"${B[@]}" "${P[@]}" --out "$OUT/train_paper_bc_$tag.json"
JAX_DEFAULT_MATMUL_PRECISION=bfloat16 "${B[@]}" "${P[@]}" --out "$OUT/train_paper_bc_bf16_$tag.json"
"${B[@]}" "${P[@]}" --updates 1 --trace "$OUT/trace_$tag" --out "$OUT/train_paper_bc_trace_$tag.json"
XLA_FLAGS="${XLA_FLAGS:-} --xla_gpu_enable_triton_gemm=false" "${B[@]}" "${P[@]}" \
    --out "$OUT/train_paper_bc_cublas_$tag.json"
