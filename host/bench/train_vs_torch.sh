#!/usr/bin/env bash
# Times `msr`'s training of the default conv decoder (burn) and its PyTorch twin on the same work,
# one after the other, and prints the ratio. Not part of the test command.
# usage: host/bench/train_vs_torch.sh [PYTHON [THREADS]]   (PYTHON must have torch and numpy;
# default python3; THREADS: both on that many threads, default each library's own choice).
# Both print the training loop's wall time and CPU seconds: on a loaded machine compare the CPU.
set -euo pipefail
cd "$(dirname "$0")/../.."
py=${1:-python3}
threads=()
if [ -n "${2:-}" ]; then
    export RAYON_NUM_THREADS=$2
    threads=(--threads "$2")
fi
burn=$(cargo test --release -q -p msr-host --lib timing_probe -- --ignored --nocapture 2>/dev/null | grep -E '^conv: ')
torch=$("$py" host/bench/torch_twin.py "${threads[@]}")
echo "burn:  $burn"
echo "$torch"
b=$(sed -E 's/.* in ([0-9.]+) s.*/\1/' <<<"$burn")
t=$(sed -E 's/.* in ([0-9.]+) s.*/\1/' <<<"$torch")
bc=$(sed -E 's/.*\(([0-9.]+) s CPU\).*/\1/' <<<"$burn")
tc=$(sed -E 's/.*\(([0-9.]+) s CPU\).*/\1/' <<<"$torch")
echo "burn / torch = $(awk -v b="$b" -v t="$t" 'BEGIN { printf "%.2f", b / t }') (wall), $(awk -v b="$bc" -v t="$tc" 'BEGIN { printf "%.2f", b / t }') (CPU seconds)"
