#!/usr/bin/env bash
# Evaluates every shipped agent as models/README.md reports it (50 graphs, seed 1000).
# Usage: bash models/evaluate_all.sh   (from the repository root, venv active)
set -euo pipefail
for preset in 1 2 3 4 5; do
    rlpgo-eval --model "models/preset$preset.zip" --preset "$preset" --graphs 50 --seed 1000 \
        --json "models/preset$preset.eval.json"
done
rlpgo-eval --model models/noisy1.zip --preset 1 --graphs 50 --seed 1000 --noisy-measurements \
    --json models/noisy1.eval.json
rlpgo-eval --model models/preset1.zip --preset 1 --graphs 50 --seed 1000 --noisy-measurements \
    --json models/preset1.noisy-eval.json
