#!/usr/bin/env bash
# Trains and evaluates the shipped agents one after another (2-core CPU machine), with the
# commands recorded in each model's metadata (models/README.md has the table).
# Usage: bash models/train_all.sh   (from the repository root, venv active)
# It replaces the shipped models in place: hence --overwrite (rlpgo-train refuses to replace
# an existing model without it, and writes under runs/ by default).
set -euo pipefail
train() {  # preset, episodes, extra options...
    local preset=$1 episodes=$2
    shift 2
    rlpgo-train --preset "$preset" --episodes "$episodes" --seed 0 --overwrite "$@"
}
train 1 400 --out models/preset1
train 2 400 --out models/preset2
train 3 700 --validation-graphs 20 --out models/preset3
train 4 400 --out models/preset4
train 5 700 --validation-graphs 20 --out models/preset5
train 1 400 --noisy-measurements --out models/noisy1
bash models/evaluate_all.sh
