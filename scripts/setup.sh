#!/usr/bin/env bash
# Creates .venv at the repository root (once) and installs the project with all
# extras, pinned by constraints.txt. Both README commands run this first.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
# the stamp covers what the install builds from: a changed kernel is rebuilt
stamp=".venv/.installed-$(cat pyproject.toml constraints.txt setup.py runtime/core/*.py \
    trainer/world/contacts.py | sha256sum | cut -c1-16)"
# the compiled decision (runtime/core, Cython at install) needs a C compiler; without one the
# install goes on and the robots decide in Python (the same numbers, slower)
if [ ! -f "$stamp" ] && ! command -v cc >/dev/null && [ "$(id -u)" -eq 0 ] \
        && command -v apt-get >/dev/null; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
        apt-get install -y -qq --no-install-recommends gcc libc6-dev) >/dev/null 2>&1 \
        || echo "setup.sh: no C compiler: the robots will decide in Python" >&2
fi
if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
if [ ! -f "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
    .venv/bin/python -m pip install --quiet --disable-pip-version-check \
        -c constraints.txt -e ".[train,sim,foxglove,distributed,ros2,dev]"
    rm -f .venv/.installed-*
    touch "$stamp"
fi
