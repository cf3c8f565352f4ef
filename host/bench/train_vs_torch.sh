#!/usr/bin/env bash
# Times `msr`'s training of the default conv decoder (burn) and its PyTorch twin on the same work,
# one after the other, and prints the ratio. Not part of the test command.
# usage: host/bench/train_vs_torch.sh [PYTHON]   (PYTHON must have torch and numpy; default python3)
set -euo pipefail
cd "$(dirname "$0")/../.."
py=${1:-python3}
burn=$(cargo test --release -q -p msr-host --lib timing_probe -- --ignored --nocapture 2>/dev/null | grep -E '^conv: ')
torch=$("$py" host/bench/torch_twin.py)
echo "burn:  $burn"
echo "$torch"
b=$(sed -E 's/.* in ([0-9.]+) s.*/\1/' <<<"$burn")
t=$(sed -E 's/.* in ([0-9.]+) s.*/\1/' <<<"$torch")
echo "burn / torch = $(awk -v b="$b" -v t="$t" 'BEGIN { printf "%.2f", b / t }')"
