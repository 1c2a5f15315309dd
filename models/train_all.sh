#!/usr/bin/env bash
# Trains and evaluates the shipped agents one after another (2-core CPU machine).
# Usage: bash models/train_all.sh [EPISODES]   (from the repository root, venv active)
set -euo pipefail
episodes=${1:-400}
for preset in 1 2 3 4 5; do
    rlpgo-train --preset "$preset" --episodes "$episodes" --seed 0 --out "models/preset$preset"
    rlpgo-eval --model "models/preset$preset.zip" --preset "$preset" --graphs 50 --seed 1000 \
        --json "models/preset$preset.eval.json"
done
rlpgo-train --preset 1 --episodes "$episodes" --seed 0 --noisy-measurements --out models/noisy1
rlpgo-eval --model models/noisy1.zip --preset 1 --graphs 50 --seed 1000 --noisy-measurements \
    --json models/noisy1.eval.json
rlpgo-eval --model models/preset1.zip --preset 1 --graphs 50 --seed 1000 --noisy-measurements \
    --json models/preset1.noisy-eval.json
