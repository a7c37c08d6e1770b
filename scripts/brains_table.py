"""Print the shipped brains' evaluations (from their manifests) as a Markdown table.

Usage: .venv/bin/python scripts/brains_table.py [exports]
Every figure comes from the brain's manifest, written by `patternrl train` after
evaluating the exported brain on 100 held-out episodes with the ORCA filter on, and
the same episodes raw (filter off) where the manifest has them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

GOAL_SUCCESS = 0.95


def raw_text(raw: dict[str, float] | None) -> str:
    """The raw (filter off) evaluation's success and collisions per episode, if measured."""
    if not raw:
        return "-"
    return f"{raw['success_rate']:.2f}, {raw['collisions_per_episode']:.2f}"


def main() -> int:
    folder = Path(sys.argv[1] if len(sys.argv) > 1 else "exports")
    rows = []
    for f in sorted(folder.glob("*.json")):
        if f.name == "manifest.json":
            continue
        m = json.loads(f.read_text())
        if m.get("format") != "patternrl-brain":
            continue
        ev, tr = m.get("evaluation") or {}, m.get("training") or {}
        ok = (ev.get("success_rate") or 0) >= GOAL_SUCCESS and ev.get("collisions", 1) == 0

        def num(key: str, ev: dict[str, float] = ev) -> str:
            v = ev.get(key)
            return "-" if v is None else f"{v:.2f}"

        rows.append(
            f"| `{m['file']}` | {m['observation']['name']} | {m.get('pattern') or 'any'} "
            f"| {tr.get('algorithm', '?')} | {tr.get('episodes', '?')} "
            f"| {tr.get('wall_time_s', '?')} | {num('success_rate')} "
            f"| {ev.get('collisions', '?')} | {num('steps_ratio')} "
            f"| {num('travel_ratio')} | {raw_text(ev.get('raw'))} | {'met' if ok else 'missed'} |"
        )
    print(
        "| brain | observation | pattern | algorithm | episodes | train s | success "
        "| collisions | steps / lb | travel / lb | raw: success, collisions / episode "
        "| goal (>= 95 %, 0 collisions) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
