#!/usr/bin/env bash
# Sets up .venv if needed, then lints and runs the whole test suite.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/setup.sh
export PYTHONHASHSEED=0
.venv/bin/ruff check .
.venv/bin/mypy runtime
.venv/bin/python -m pytest "$@"
