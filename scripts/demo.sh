#!/usr/bin/env bash
# Sets up .venv if needed, then runs the swarm demo (see README).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/setup.sh
exec .venv/bin/patternrl launch "$@"
