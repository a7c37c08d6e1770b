#!/usr/bin/env bash
# Sets up .venv if needed, then lints and runs the whole test suite.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
scripts/setup.sh
# tests/netns builds hosts from network namespaces: it needs ip (iproute2) and nft (nftables)
if ! command -v ip >/dev/null || ! command -v nft >/dev/null; then
    if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null; then
        if ! (apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
              apt-get install -y -qq --no-install-recommends iproute2 nftables) >/dev/null 2>&1; then
            echo "test.sh: could not install iproute2 and nftables (needed by tests/netns)" >&2
            exit 1
        fi
    else
        echo "test.sh: tests/netns needs 'ip' and 'nft' (iproute2, nftables) and root" >&2
    fi
fi
export PYTHONHASHSEED=0
.venv/bin/ruff check .
.venv/bin/mypy runtime
.venv/bin/python -m pytest "$@"
