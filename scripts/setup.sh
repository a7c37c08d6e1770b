#!/usr/bin/env bash
# Creates .venv at the repository root (once) and installs the project with all
# extras, pinned by constraints.txt. Both README commands run this first.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
stamp=".venv/.installed-$(cat pyproject.toml constraints.txt | sha256sum | cut -c1-16)"
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
if [ ! -f "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
    .venv/bin/python -m pip install --quiet --disable-pip-version-check \
        -c constraints.txt -e ".[train,sim,foxglove,distributed,dev]"
    rm -f .venv/.installed-*
    touch "$stamp"
fi
