#!/bin/bash
# One core against two: the same (setting, method) grid - BC, Full and Gauss, 3 seeds, N
# updates of the laptop profile, one XLA thread per worker - as one worker on core 0, then as
# two workers (one setting each) on cores 0 and 1 side by side. Prints both wall times and
# the speed-up. Usage: bash scripts/bench_cores.sh WORK [N]   (WORK: a reproduce.sh --out
# folder with filtered/ data, e.g. outputs/laptop; N defaults to 150)
set -euo pipefail
for arg in "$@"; do
    if [ "$arg" = "--help" ] || [ "$arg" = "-h" ]; then
        cat <<'EOF'
usage: bash scripts/bench_cores.sh WORK [N]

One core against two: BC on Full and Gauss (3 seeds, N updates of the laptop profile, one XLA
thread per worker) as one worker on core 0, then as two workers on cores 0 and 1; prints both
wall times and the speed-up. Needs taskset and two cores.

  WORK  a reproduce.sh --out folder with filtered/ data, e.g. outputs/laptop (required; its
        cache/ and jax_cache/ are reused)
  N     training updates per run (default: 150)
  -h, --help  print this help and exit (runs nothing)
EOF
        exit 0
    fi
done
work=${1:?usage: bash scripts/bench_cores.sh WORK [N]}
n=${2:-150}
out=$(mktemp -d)
export XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
export JAX_COMPILATION_CACHE_DIR="$work/jax_cache"
common=(--profile laptop --method bc --seeds 3 --data "$work/filtered/training"
        --val-data "$work/filtered/validation" --cache-dir "$work/cache" --no-progress
        --set "training.num_updates=$n" --set training.eval_every=0
        --set training.checkpoint_every=100000)
t0=$(date +%s.%N)
taskset -c 0 igdrivsim train "${common[@]}" --obs full,gaussian_noise --out "$out/one" >/dev/null
t1=$(date +%s.%N)
taskset -c 0 igdrivsim train "${common[@]}" --obs full --out "$out/a" >/dev/null &
taskset -c 1 igdrivsim train "${common[@]}" --obs gaussian_noise --out "$out/b" >/dev/null &
wait
t2=$(date +%s.%N)
python -c "a = $t1 - $t0; b = $t2 - $t1; print(f'1 core, one worker: {a:.0f} s; 2 cores, two workers: {b:.0f} s; speed-up {a / b:.2f}x')"
rm -rf "$out"
