#!/usr/bin/env bash
# Retrains the shipped brains in exports/ (the commands that made them).
# Usage: scripts/train_shipped.sh [general|paper|any|all]   (default all)
# Budgets are wall-clock seconds on a 2-core machine; each brain's manifest
# records what it reached (episodes, wall time, evaluation over 100 held-out episodes).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/setup.sh
what="${1:-all}"
train() { .venv/bin/patternrl train --robots 10 --final-eval-episodes 100 --no-progress --json "$@"; }

if [ "$what" = general ] || [ "$what" = all ]; then
    for p in circle cross line heart triangle; do
        train --pattern "$p" --obs general --seed 0 --episodes 100000 \
            --time-budget-s "${GENERAL_BUDGET_S:-120}" --out "exports/$p-10-general.onnx"
    done
fi
if [ "$what" = paper ] || [ "$what" = all ]; then
    for p in circle cross line heart triangle; do
        # Algorithm 1 on the paper's observation; the brain's front end matches the team to
        # its pattern by optimal transport (docs/paper_observation.md)
        train --pattern "$p" --obs paper --seed 0 --until-success 0.99 \
            --time-budget-s "${PAPER_BUDGET_S:-600}" --out "exports/$p-10-paper.onnx"
    done
fi
if [ "$what" = any ] || [ "$what" = all ]; then
    # random shapes only (the built-ins stay unseen, for benchmarks/general_brain.py):
    # 10 robots first, then fine-tuned on 20 so that denser teams are seen too
    train --pattern random --obs general --seed 0 --episodes 100000 \
        --time-budget-s "${ANY_BUDGET_S:-240}" --out exports/general-stage1.onnx
    train --pattern random --obs general --seed 1 --robots 20 --episodes 100000 \
        --init exports/general-stage1.onnx --time-budget-s "${ANY_BUDGET_S:-240}" \
        --out exports/general.onnx
    rm -f exports/general-stage1.*
fi
